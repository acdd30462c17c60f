#!/bin/sh
# Runs every fuzz target of a build for SECONDS each; fails when one finds a crash.
#   test/fuzz/run-fuzzers.sh BUILD_DIR SECONDS
# BUILD_DIR is a build made with the `fuzz` preset (clang, -DOCTOFUSE_FUZZ=ON), e.g. build/fuzz.
set -eu

if [ $# -ne 2 ]; then
  echo "usage: $0 BUILD_DIR SECONDS" >&2
  exit 2
fi
build_dir=$1
seconds=$2
here=$(cd "$(dirname "$0")" && pwd)
fuzz_dir="$build_dir/test/fuzz"

targets=$(find "$fuzz_dir" -maxdepth 1 -type f -name 'fuzz_*' -perm -u+x 2>/dev/null | sort)
if [ -z "$targets" ]; then
  echo "error: no fuzz targets in $fuzz_dir (configure with the fuzz preset and build first)" >&2
  exit 2
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/octofuse-fuzz.XXXXXX")
failed=0
for target in $targets; do
  name=$(basename "$target")
  corpus="$work/$name/corpus"
  artifacts="$work/$name/artifacts"
  mkdir -p "$corpus" "$artifacts"
  seeds="$here/corpus/$name"
  [ -d "$seeds" ] || seeds=""
  echo "== $name: ${seconds}s"
  # shellcheck disable=SC2086  # $seeds is empty or one directory
  if "$target" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
      -artifact_prefix="$artifacts/" -print_final_stats=1 "$corpus" $seeds \
      >"$work/$name/log" 2>&1; then
    grep -E '^stat::number_of_executed_units|^#[0-9]+.*DONE' "$work/$name/log" | tail -2 || true
  else
    failed=1
    echo "error: $name failed; last lines of its log:" >&2
    tail -30 "$work/$name/log" >&2
    ls "$artifacts" >&2
  fi
done

if [ "$failed" -ne 0 ]; then
  echo "fuzzing found problems; logs and crash inputs under $work" >&2
  exit 1
fi
rm -rf "$work"
echo "all fuzz targets ran ${seconds}s without a crash"
