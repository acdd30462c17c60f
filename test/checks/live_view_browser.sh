#!/usr/bin/env bash
# The live view in a real headless browser, on loopback: runs octofuse-replay --serve, loads the
# page twice in headless Chromium and checks that it shows a rendered frame and that the frame
# number moves on between the two loads.
#   live_view_browser.sh OCTOFUSE_REPLAY CHROMIUM WORK_DIR
set -euo pipefail
replay=$1
chromium=$2
work=$3
rm -rf "${work}"
mkdir -p "${work}"
port=$((20000 + RANDOM % 20000))

"${replay}" --source sim:desk --frames 2000 --voxel-size 0.04 --quiet --no-mesh \
  --out "${work}/out" --serve "127.0.0.1:${port}" >"${work}/replay.log" 2>&1 &
replay_pid=$!
trap 'kill ${replay_pid} 2>/dev/null || true; wait ${replay_pid} 2>/dev/null || true' EXIT

# Wait (bounded) for the server.
for _ in $(seq 1 100); do
  grep -q "live view at" "${work}/replay.log" && break
  sleep 0.1
done
grep -q "live view at http://127.0.0.1:${port}/" "${work}/replay.log" || {
  echo "error: no live view announced:"; cat "${work}/replay.log"; exit 1; }

load() {
  timeout 60 "${chromium}" --headless --no-sandbox --disable-gpu --no-first-run \
    --disable-background-networking --disable-component-update --disable-sync \
    --disable-default-apps --user-data-dir="${work}/profile-$1" \
    --virtual-time-budget=3000 --dump-dom "http://127.0.0.1:${port}/" 2>"${work}/chromium-$1.log"
}
attribute() {  # attribute NAME FILE: the value of data-NAME on <body>
  sed -n "s/.*<body[^>]* data-$1=\"\([0-9]*\)\".*/\1/p" "$2" | head -n 1
}

load 1 >"${work}/dom-1.html"
sleep 2
load 2 >"${work}/dom-2.html"

frame1=$(attribute frame "${work}/dom-1.html")
frame2=$(attribute frame "${work}/dom-2.html")
width2=$(attribute render-width "${work}/dom-2.html")
echo "first load: frame ${frame1:-none}; second load: frame ${frame2:-none}, render width ${width2:-none}"
[[ -n "${frame1}" && -n "${frame2}" ]] || { echo "error: the page showed no frame"; exit 1; }
[[ "${width2}" == "320" ]] || { echo "error: the page showed no 320-pixel ray-cast"; exit 1; }
(( frame2 > frame1 )) || { echo "error: the frame did not move on (${frame1} -> ${frame2})"; exit 1; }
grep -q 'id="state"[^>]*>tracked<' "${work}/dom-2.html" || { echo "error: no tracking state"; exit 1; }
echo "live view ok"
