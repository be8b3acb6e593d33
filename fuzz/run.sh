#!/usr/bin/env bash
# Runs every fuzz target (or the ones named) for SECONDS each (default 60),
# one after the other in one process each, with a 1 GiB memory limit and a
# per-input time limit. Exits non-zero if any target found a crash, a hang
# or an allocation over the limit; its input is left in fuzz/artifacts/<target>/.
#
#   fuzz/run.sh [SECONDS] [TARGET...]
#
# cargo-fuzz needs unstable compiler flags: a nightly toolchain when rustup
# has one, else the stable compiler with RUSTC_BOOTSTRAP=1. Without either,
# or without cargo-fuzz (`cargo install cargo-fuzz`), it says so and skips.
# Not part of `cargo test`. Env: FUZZ_SANITIZER (address, the default, or
# none: faster, but a huge allocation is then only caught by its RSS),
# FUZZ_TIMEOUT (seconds per input, default 10), FUZZ_TOOLCHAIN (auto, the
# default: nightly if rustup has it, else bootstrap; nightly; bootstrap).
set -uo pipefail
cd "$(dirname "$0")"

seconds=${1:-60}
shift || true
if ! [[ "$seconds" =~ ^[0-9]+$ ]] || [ "$seconds" -eq 0 ]; then
  echo "usage: fuzz/run.sh [SECONDS] [TARGET...]" >&2
  exit 2
fi
sanitizer=${FUZZ_SANITIZER:-address}
per_input=${FUZZ_TIMEOUT:-10}

if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz/run.sh: skipped: cargo-fuzz is not installed (cargo install cargo-fuzz)"
  exit 0
fi
toolchain=()
route=${FUZZ_TOOLCHAIN:-auto}
if [ "$route" != bootstrap ] && rustup run nightly rustc --version >/dev/null 2>&1; then
  toolchain=(+nightly)
  echo "fuzz/run.sh: using the nightly toolchain: $(rustup run nightly rustc --version)"
elif [ "$route" != nightly ] && RUSTC_BOOTSTRAP=1 rustc -Z unstable-options --print sysroot >/dev/null 2>&1; then
  export RUSTC_BOOTSTRAP=1
  echo "fuzz/run.sh: using $(rustc --version) with RUSTC_BOOTSTRAP=1 (no nightly toolchain, or FUZZ_TOOLCHAIN=bootstrap)"
else
  echo "fuzz/run.sh: skipped: no nightly toolchain, and the compiler refuses RUSTC_BOOTSTRAP (FUZZ_TOOLCHAIN=$route)"
  exit 0
fi

if [ $# -gt 0 ]; then
  targets=("$@")
else
  mapfile -t targets < <(cargo "${toolchain[@]}" fuzz list)
fi

echo "fuzz/run.sh: building ${targets[*]} (sanitizer: $sanitizer)"
cargo "${toolchain[@]}" fuzz build --sanitizer "$sanitizer" || exit 1

failed=()
for target in "${targets[@]}"; do
  # New inputs go to a scratch corpus; the checked-in seeds are only read.
  mkdir -p "corpus-work/$target" "corpus/$target"
  # A dictionary of the tokens a target's format is made of, where there is one.
  dict=()
  if [ -f "dict/$target.dict" ]; then
    dict=(-dict="dict/$target.dict")
  fi
  echo "fuzz/run.sh: $target for ${seconds} s"
  if ! cargo "${toolchain[@]}" fuzz run --sanitizer "$sanitizer" "$target" "corpus-work/$target" "corpus/$target" -- \
      -max_total_time="$seconds" -rss_limit_mb=1024 -malloc_limit_mb=1024 -timeout="$per_input" -print_final_stats=1 "${dict[@]}"; then
    failed+=("$target")
  fi
done

if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz/run.sh: FAILED: ${failed[*]} (inputs in fuzz/artifacts/)"
  exit 1
fi
echo "fuzz/run.sh: ${#targets[@]} targets, ${seconds} s each: no crash"
