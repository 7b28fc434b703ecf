#!/usr/bin/env bash
# Builds the AFL++ binaries (cargo-afl) and fuzzes one target for a time, on one core.
#   fuzz/run.sh TARGET SECONDS     fuzz TARGET (see fuzz/harness/src/lib.rs) from its corpus
#   fuzz/run.sh all SECONDS        every target in turn, SECONDS each
#   fuzz/run.sh build              build only
# FUZZ_EXECS=N stops a target after about N executions (AFL's -E) if that comes first.
# Needs `cargo install cargo-afl` and `cargo afl config --build` once. Findings land in
# fuzz/out/<target>/default/{crashes,hangs}; the campaign figures in .../fuzzer_stats.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
target_dir="${CARGO_TARGET_DIR:-$here/../target}/afl"
targets=(carmen ros1_bag mcap ucsd_encoder ucsd_fog ucsd_lidar ucsd_calib opencv_yaml humanoid
  tum map_server npy relations config_toml session_state)

build() {
  (cd "$here/afl" && CARGO_TARGET_DIR="$target_dir" cargo afl build --release -q)
}

fuzz_one() {
  local t="$1" secs="$2"
  [[ " ${targets[*]} " == *" $t "* ]] || { echo "unknown target $t (one of: ${targets[*]})" >&2; exit 2; }
  [[ -d "$here/corpus/$t" ]] || { echo "no seeds for $t: run fuzz/scripts/seeds.sh first (it cuts them from \$PFSLAM_DATA)" >&2; exit 2; }
  local out="$here/out/$t" scratch
  # the bag target's scratch file is rewritten per input: keep it in memory where possible
  local tmp_root="${TMPDIR:-/tmp}"
  [[ -d /dev/shm ]] && tmp_root=/dev/shm
  scratch="$(mktemp -d "$tmp_root/pfslam-fuzz.XXXXXX")"
  mkdir -p "$out"
  # resume an earlier run of this target when there is one
  local input="$here/corpus/$t"
  [[ -f "$out/default/fuzzer_stats" ]] && input=-
  # -t: an input taking over 1 s is a hang; -m none: CappedAlloc bounds allocations
  AFL_SKIP_CPUFREQ=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_NO_UI=1 \
    AFL_SKIP_CRASHES=1 PFSLAM_FUZZ_TMP="$scratch" \
    cargo afl fuzz -i "$input" -o "$out" -t 1000 -m none -V "$secs" ${FUZZ_EXECS:+-E "$FUZZ_EXECS"} \
    -- "$target_dir/release/$t" > "$out/log.txt" 2>&1 \
    || { rm -rf "$scratch"; tail -20 "$out/log.txt" >&2; return 1; }
  rm -rf "$scratch"
  local s="$out/default/fuzzer_stats"
  printf '%-13s %s\n' "$t" "$(awk -F' *: *' '
    /^execs_done/{e=$2} /^execs_per_sec/{r=$2} /^bitmap_cvg/{b=$2} /^edges_found/{g=$2}
    /^saved_crashes/{c=$2} /^saved_hangs/{h=$2} /^run_time/{t=$2}
    END{printf "execs %s  exec/s %s  edges %s  bitmap %s  crashes %s  hangs %s  time %ss", e, r, g, b, c, h, t}' "$s")"
}

case "${1:-}" in
  build) build ;;
  all) build; for t in "${targets[@]}"; do fuzz_one "$t" "${2:?SECONDS}"; done ;;
  "") sed -n '2,7p' "$0"; exit 2 ;;
  *) build; fuzz_one "$1" "${2:?SECONDS}" ;;
esac
