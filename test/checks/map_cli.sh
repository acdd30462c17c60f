#!/usr/bin/env bash
# The map commands as a user runs them: octofuse-replay --save-map / --save-every / --load-map
# and octofuse-map info / mesh on the sim, then damaged, foreign and newer map files, which must
# end the run before any frame with one "error: FILE: ..." line and a non-zero exit.
# With OCTOFUSE-LIVE it also stops octofuse-live with SIGTERM once it reports a frame and checks
# that the map it wrote on the way out loads.
# Usage: map_cli.sh OCTOFUSE-REPLAY OCTOFUSE-MAP WORK-DIR [OCTOFUSE-LIVE]
set -uo pipefail
replay=$1
map=$2
work=$3
live=${4:-}
rm -rf "${work}"
mkdir -p "${work}"
failures=0
fail() {
  echo "FAIL: $*"
  failures=$((failures + 1))
}
# Fused at the sim's true poses: these runs are about map files, and a run whose frames after the
# first are all lost (a coarse two-frame single-res map, a camera placed by --initial-pose away
# from the truth) ends non-zero by design.
common=(--source sim:desk --voxel-size 0.04 --gt-poses --quiet)

# expect_error NAME EXPECTED-TEXT COMMAND...: non-zero exit, stderr one line "error: ...TEXT..."
expect_error() {
  local name=$1 text=$2
  shift 2
  "$@" >"${work}/${name}.out" 2>"${work}/${name}.err"
  local rc=$?
  [[ ${rc} -ne 0 ]] || fail "${name}: exit 0"
  [[ $(wc -l <"${work}/${name}.err") -eq 1 ]] || fail "${name}: stderr is not one line: $(cat "${work}/${name}.err")"
  grep -q "^error: .*${text}" "${work}/${name}.err" || fail "${name}: no '${text}' in: $(cat "${work}/${name}.err")"
}

"${replay}" "${common[@]}" --frames 4 --out "${work}/a" --save-map "${work}/a.ofmap" --save-every 2 \
  >"${work}/a.out" 2>&1 || fail "save run: $(cat "${work}/a.out")"
grep -q "3 saves" "${work}/a.out" || fail "save run: expected 3 saves (2 periodic, 1 final): $(cat "${work}/a.out")"
[[ ! -e "${work}/a.ofmap.tmp" ]] || fail "temporary left behind"

"${map}" info "${work}/a.ofmap" >"${work}/info.out" 2>&1 || fail "info: $(cat "${work}/info.out")"
grep -q "^format version  2$" "${work}/info.out" || fail "info: no format version"
grep -q "^voxel size      0.04 m$" "${work}/info.out" || fail "info: no voxel size"
grep -q "^frames          4$" "${work}/info.out" || fail "info: no frame count"
grep -q "^free space      [1-9][0-9]* nodes, " "${work}/info.out" || fail "info: no free-space nodes"
grep -q "^coarse blocks   [1-9][0-9]* would hold the [1-9][0-9]* fused blocks$" "${work}/info.out" || fail "info: no coarse estimate"
# A fused block holds a mid level exactly when it fused at scale 1 or 0 (nothing was demoted).
awk '/^  at scale [01] /{fine += $4} /^mid levels /{mid = $3; seen = 1}
     END{exit !(seen && mid == fine)}' "${work}/info.out" || fail "info: mid levels not the blocks at scales 0-1"
"${map}" mesh "${work}/a.ofmap" "${work}/a_mesh.ply" >/dev/null 2>&1 || fail "mesh failed"
cmp -s "${work}/a_mesh.ply" "${work}/a/mesh.ply" || fail "octofuse-map mesh differs from the run's mesh.ply"
# compare: a mesh lies on itself, every vertex of it both ways.
"${map}" compare "${work}/a_mesh.ply" "${work}/a/mesh.ply" --within 0.001 >"${work}/cmp.out" 2>&1 ||
  fail "compare: $(cat "${work}/cmp.out")"
[[ $(grep -c "surface: 100.0 % within 0.001 m, 100.0 % within 0.002 m; median 0.00 mm" \
  "${work}/cmp.out") -eq 2 ]] || fail "compare: a mesh is not on itself: $(cat "${work}/cmp.out")"

"${replay}" "${common[@]}" --frames 2 --out "${work}/b" --load-map "${work}/a.ofmap" \
  >"${work}/b.out" 2>&1 || fail "load run: $(cat "${work}/b.out")"
grep -q "^loaded .*: [0-9]* blocks, [1-9][0-9]* free-space nodes" "${work}/b.out" ||
  fail "load run: no 'loaded' line with free-space nodes: $(cat "${work}/b.out")"

# Without free space: saved without it, loaded into a run that records it (which starts knowing
# nothing free), and a file with free space loaded into a run without it.
"${replay}" "${common[@]}" --gt-poses --frames 2 --no-free-space --out "${work}/n" \
  --save-map "${work}/n.ofmap" >"${work}/n.out" 2>&1 || fail "--no-free-space save: $(cat "${work}/n.out")"
"${map}" info "${work}/n.ofmap" >"${work}/ninfo.out" 2>&1 || fail "info n: $(cat "${work}/ninfo.out")"
grep -q "^free space      not saved$" "${work}/ninfo.out" || fail "info n: free space not reported absent"
"${replay}" "${common[@]}" --gt-poses --frames 2 --out "${work}/nl" --load-map "${work}/n.ofmap" \
  >"${work}/nl.out" 2>&1 || fail "load without free space: $(cat "${work}/nl.out")"
grep -q "^loaded .* 0 free-space nodes" "${work}/nl.out" || fail "load n: $(cat "${work}/nl.out")"
"${replay}" "${common[@]}" --gt-poses --frames 2 --no-free-space --out "${work}/nf" \
  --load-map "${work}/a.ofmap" >"${work}/nf.out" 2>&1 || fail "--no-free-space load: $(cat "${work}/nf.out")"

# A damaged free-space record (the last one, just before the 17-byte end record).
cp "${work}/a.ofmap" "${work}/freebad.ofmap"
size=$(stat -c %s "${work}/freebad.ofmap")
printf '\x5a' | dd of="${work}/freebad.ofmap" bs=1 seek=$((size - 17 - 20)) conv=notrunc status=none
expect_error freebad "freebad.ofmap: checksum mismatch in free-space record" "${map}" info \
  "${work}/freebad.ofmap"
expect_error freebad_load "freebad.ofmap: checksum mismatch in free-space record" "${replay}" \
  "${common[@]}" --out "${work}/c" --load-map "${work}/freebad.ofmap"
"${replay}" "${common[@]}" --frames 2 --out "${work}/p" --load-map "${work}/a.ofmap" \
  --initial-pose 0,0,0,0,0,0,1 >"${work}/p.out" 2>&1 || fail "--initial-pose run: $(cat "${work}/p.out")"

# A single-resolution map: --load-map takes the voxel type from the file, whatever --map says.
"${replay}" "${common[@]}" --map single --frames 2 --out "${work}/s" --save-map "${work}/s.ofmap" \
  >"${work}/s.out" 2>&1 || fail "single-res save run: $(cat "${work}/s.out")"
"${map}" info "${work}/s.ofmap" | grep -q "^voxel type      single-res$" || fail "single-res info"
"${replay}" "${common[@]}" --map multires --frames 2 --out "${work}/s2" --load-map "${work}/s.ofmap" \
  --save-map "${work}/s2.ofmap" >"${work}/s2.out" 2>&1 || fail "single-res load run: $(cat "${work}/s2.out")"
"${map}" info "${work}/s2.ofmap" | grep -q "^voxel type      single-res$" || fail "single-res reloaded"

head -c 700 "${work}/a.ofmap" >"${work}/cut.ofmap"
expect_error cut "cut.ofmap: truncated" "${replay}" "${common[@]}" --out "${work}/c" \
  --load-map "${work}/cut.ofmap"
[[ ! -s "${work}/c/trajectory.txt" ]] || fail "cut: frames were processed"
expect_error foreign "mesh.ply: not an octofuse map" "${replay}" "${common[@]}" --out "${work}/c" \
  --load-map "${work}/a/mesh.ply"
cp "${work}/a.ofmap" "${work}/newer.ofmap"
printf '\x09' | dd of="${work}/newer.ofmap" bs=1 seek=8 conv=notrunc status=none
expect_error newer "newer.ofmap: format version 9 is newer" "${replay}" "${common[@]}" \
  --out "${work}/c" --load-map "${work}/newer.ofmap"
cp "${work}/a.ofmap" "${work}/flipped.ofmap"
printf '\xff' | dd of="${work}/flipped.ofmap" bs=1 seek=2000 conv=notrunc status=none
expect_error flipped "flipped.ofmap: " "${map}" info "${work}/flipped.ofmap"
expect_error missing "none.ofmap: cannot open" "${map}" mesh "${work}/none.ofmap" "${work}/x.ply"
expect_error small "needs .* blocks" "${replay}" "${common[@]}" --out "${work}/c" \
  --load-map "${work}/a.ofmap" --max-blocks 10
expect_error every "--save-every needs --save-map" "${replay}" --save-every 3
expect_error pose "--initial-pose needs" "${replay}" --initial-pose 1,2,3,0,0,0,5
expect_error command "unknown command" "${map}" show "${work}/a.ofmap"
expect_error within "--within needs metres" "${map}" compare "${work}/a_mesh.ply" \
  "${work}/a_mesh.ply" --within 0
expect_error no_mesh "none.ply" "${map}" compare "${work}/a_mesh.ply" "${work}/none.ply"
expect_error not_mesh "a.ofmap" "${map}" compare "${work}/a.ofmap" "${work}/a_mesh.ply"

# A block store (--map-file) of a run whose map memory holds a fraction of the room: octofuse-map
# reads it as it is (nothing written, a torn tail only warned about) and refuses a damaged header.
"${replay}" --source sim:room --voxel-size 0.04 --gt-poses --quiet --frames 60 --map-memory 1 \
  --map-file "${work}/k.store" --save-map "${work}/k.ofmap" --out "${work}/k" >"${work}/k.out" 2>&1 ||
  fail "--map-file run: $(cat "${work}/k.out")"
# The run's mesh.ply is the whole map's (memory and store), as its --save-map file is.
"${map}" mesh "${work}/k.ofmap" "${work}/k_saved.ply" >/dev/null 2>&1 || fail "saved map mesh failed"
cmp -s "${work}/k_saved.ply" "${work}/k/mesh.ply" ||
  fail "a --map-file run's mesh.ply is not the mesh of its whole map"
# Finest levels the 1 MB run gave up for room lie beside it, in FILE.fine: the whole map (its
# saved file, and octofuse-map given the store) merges them; given alone, or another map's, refused.
[[ -s "${work}/k.store.fine" ]] || fail "no finest-level store beside the block store"
"${map}" info "${work}/k.store" >"${work}/kfine.out" 2>&1 || fail "store info: $(cat "${work}/kfine.out")"
grep -q "^finest levels   [1-9][0-9]* records in .*k.store.fine (merged)$" "${work}/kfine.out" ||
  fail "store info: finest-level store not merged: $(cat "${work}/kfine.out")"
expect_error finealone "a finest-level store; give its block store" "${map}" info \
  "${work}/k.store.fine"
# Off: no finest-level store, the rest as before.
"${replay}" --source sim:room --voxel-size 0.04 --gt-poses --quiet --frames 20 --map-memory 1 \
  --map-file "${work}/koff.store" --map-file-finest off --out "${work}/koff" >"${work}/koff.out" 2>&1 ||
  fail "--map-file-finest off run: $(cat "${work}/koff.out")"
[[ -s "${work}/koff.store" && ! -e "${work}/koff.store.fine" ]] ||
  fail "--map-file-finest off: a finest-level store was made, or no block store"
expect_error fineflag "map-file-finest needs on or off" "${replay}" --source sim:room \
  --map-file "${work}/kx.store" --map-file-finest maybe --out "${work}/kx"
cp "${work}/k.store" "${work}/k.copy"
"${map}" info "${work}/k.store" >"${work}/kinfo.out" 2>&1 || fail "store info: $(cat "${work}/kinfo.out")"
grep -q "a block store, every record checked" "${work}/kinfo.out" || fail "store info: not read as a store"
grep -q "^blocks          [1-9][0-9]*$" "${work}/kinfo.out" || fail "store info: no blocks"
grep -q "^voxel size      0.04 m$" "${work}/kinfo.out" || fail "store info: no voxel size"
cmp -s "${work}/k.store" "${work}/k.copy" || fail "store info changed the store"
"${map}" mesh "${work}/k.store" "${work}/k_store.ply" >/dev/null 2>&1 || fail "store mesh failed"
[[ $(stat -c %s "${work}/k_store.ply") -gt 1000 ]] || fail "store mesh is empty"
size=$(stat -c %s "${work}/k.store")
head -c $((size - 10)) "${work}/k.store" >"${work}/kcut.store"
"${map}" info "${work}/kcut.store" >"${work}/kcut.out" 2>"${work}/kcut.err" ||
  fail "cut store: $(cat "${work}/kcut.err")"
grep -q "^warning: .*torn or damaged tail" "${work}/kcut.err" || fail "cut store: no warning"
[[ $(stat -c %s "${work}/kcut.store") -eq $((size - 10)) ]] || fail "cut store: info truncated it"
cp "${work}/k.store" "${work}/kbad.store"
printf '\xff' | dd of="${work}/kbad.store" bs=1 seek=20 conv=notrunc status=none
expect_error storebad "kbad.store: block store header damaged" "${map}" info "${work}/kbad.store"

# At 2 cm the free-space pool is too small for the room: the air it forgets goes beside the store,
# to FILE.free, by region. octofuse-map reads it with its store (a cut one with a warning), refuses
# it alone, and --save-map writes it into the map with the air still in memory.
"${replay}" --source sim:room --voxel-size 0.02 --gt-poses --quiet --frames 60 --map-memory 1 \
  --map-file "${work}/f.store" --save-map "${work}/f.ofmap" --out "${work}/f" >"${work}/f.out" 2>&1 ||
  fail "--map-file run at 2 cm: $(cat "${work}/f.out")"
[[ -s "${work}/f.store.free" ]] || fail "no free-space store beside the block store"
"${map}" info "${work}/f.store" >"${work}/finfo.out" 2>&1 || fail "store info: $(cat "${work}/finfo.out")"
stored_free=$(sed -n 's/^free space      \([0-9]*\) nodes, .* from \([1-9][0-9]*\) stored regions.*/\1/p' \
  "${work}/finfo.out")
[[ -n "${stored_free}" && "${stored_free}" -gt 1 ]] || fail "store info: no stored free space: $(cat "${work}/finfo.out")"
"${map}" info "${work}/f.ofmap" >"${work}/fmap.out" 2>&1 || fail "map info: $(cat "${work}/fmap.out")"
saved_free=$(sed -n 's/^free space      \([0-9]*\) nodes.*/\1/p' "${work}/fmap.out")
[[ -n "${saved_free}" && "${saved_free}" -ge "${stored_free}" ]] ||
  fail "the saved map holds ${saved_free} free-space nodes, the store alone ${stored_free}"
expect_error freealone "a free-space store; give its block store" "${map}" info "${work}/f.store.free"
cp "${work}/f.store" "${work}/fcut.store"
free_size=$(stat -c %s "${work}/f.store.free")
head -c $((free_size - 10)) "${work}/f.store.free" >"${work}/fcut.store.free"
"${map}" info "${work}/fcut.store" >"${work}/fcut.out" 2>"${work}/fcut.err" ||
  fail "cut free-space store: $(cat "${work}/fcut.err")"
grep -q "^warning: .*torn or damaged tail" "${work}/fcut.err" || fail "cut free-space store: no warning"
# Another map's finest-level store beside a block store (4 cm levels beside a 2 cm store).
cp "${work}/f.store" "${work}/fmix.store"
cp "${work}/k.store.fine" "${work}/fmix.store.fine"
expect_error finemix "fmix.store.fine: not the finest-level store of" "${map}" info \
  "${work}/fmix.store"
cp "${work}/f.store" "${work}/fmix2.store"
cp "${work}/k.store.free" "${work}/fmix2.store.free"
expect_error freemix "fmix2.store.free: not the free space of" "${map}" info "${work}/fmix2.store"

if [[ -n "${live}" ]]; then
  "${live}" "${common[@]}" --frames 100000 --out "${work}/l" --save-map "${work}/live.ofmap" \
    >"${work}/live.out" 2>&1 &
  pid=$!
  # Its status line comes once a second; wait for one (at most 120 s), then stop it.
  for _ in $(seq 1200); do
    grep -q " fps " "${work}/live.out" 2>/dev/null && break
    sleep 0.1
  done
  kill -TERM "${pid}"
  wait "${pid}" || fail "live: non-zero exit after SIGTERM: $(cat "${work}/live.out")"
  "${map}" info "${work}/live.ofmap" >"${work}/live_info.out" 2>&1 ||
    fail "live: map written on SIGTERM does not load: $(cat "${work}/live_info.out")"
fi

if [[ ${failures} -ne 0 ]]; then
  echo "map_cli: ${failures} failure(s)"
  exit 1
fi
echo "map_cli: all checks passed"
