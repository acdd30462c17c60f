#!/usr/bin/env bash
# Instructions per frame of octofuse-replay, counted by valgrind's callgrind: unlike wall time it
# is repeatable on a busy machine, and it is the figure to compare host and ARM builds by (run the
# ARM binary under qemu with the same arguments; callgrind counts the guest's instructions only
# on a native ARM board, so there run this script directly).
#
# usage: count-instructions.sh BUILD_DIR [FRAMES] [extra octofuse-replay args...]
# Prints the total and per-frame instruction counts of the whole run and of each pipeline stage
# (inclusive counts of Pipeline::process and the stage entry points). Start-up and the first
# frame are included in the averages, so use enough frames (default 20).
set -euo pipefail

build_dir=${1:?usage: count-instructions.sh BUILD_DIR [FRAMES] [args...]}
frames=${2:-20}
[[ "${frames}" =~ ^[1-9][0-9]*$ ]] || { echo "error: FRAMES must be a positive integer, not '${frames}'" >&2; exit 2; }
shift $(( $# >= 2 ? 2 : 1 ))
replay="${build_dir}/examples/octofuse-replay/octofuse-replay"
[[ -x "${replay}" ]] || { echo "error: ${replay} not built" >&2; exit 1; }
command -v valgrind >/dev/null || { echo "error: valgrind not installed" >&2; exit 1; }
command -v callgrind_annotate >/dev/null || { echo "error: callgrind_annotate missing" >&2; exit 1; }

work=$(mktemp -d)
trap 'rm -rf "${work}"' EXIT
valgrind --tool=callgrind --callgrind-out-file="${work}/cg.out" \
  "${replay}" --frames "${frames}" --out "${work}/out" --quiet --no-mesh "$@" >/dev/null 2>"${work}/log" ||
  { cat "${work}/log" >&2; exit 1; }

callgrind_annotate --inclusive=yes "${work}/cg.out" > "${work}/annotated" 2>/dev/null
total=$(grep -m1 "PROGRAM TOTALS" "${work}/annotated" | awk '{gsub(",","",$1); print $1}')
echo "frames: ${frames}"
printf '%-34s %16s %14s\n' "function (inclusive)" "instructions" "per frame"
printf '%-34s %16s %14d\n' "whole program" "${total}" $(( total / frames ))
for symbol in "Pipeline<.*>::process" "DepthPreprocessor::process" "IcpTracker::track" \
              "Integrator<.*>::integrate" "FreeSpace::carve" "Raycaster<.*>::raycast" \
              "SimSource::next" \
              "ReplaySource::next"; do
  # A stage the run never entered (no ICP on a one-frame run, no sim port for a recording) is
  # absent from the profile: grep finds nothing, which must not end the script under pipefail.
  count=$( { grep -E "octofuse::${symbol}\(" "${work}/annotated" || true; } | head -1 |
    awk '{gsub(",","",$1); print $1}')
  [[ -n "${count}" ]] || continue
  printf '%-34s %16s %14d\n' "${symbol}" "${count}" $(( count / frames ))
done
