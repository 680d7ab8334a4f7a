#!/usr/bin/env bash
# granseg's two commands (and a few helpers). Needs only python3 (>= 3.11)
# and a Rust toolchain; everything else is installed into ./.venv.
#
#   ./dev.sh demo     set up, then run the demo on the embedded data
#   ./dev.sh test     set up, then run every test (Rust and Python)
#   ./dev.sh bench    set up, then run the benchmarks behind BENCHMARKS.md
set -euo pipefail
cd "$(dirname "$0")"

# Opt-in: a build tuned to this machine's CPU (faster, but crashes on an older CPU);
# kept in its own target folder so switching does not rebuild the portable one.
if [ "${GRANSEG_NATIVE:-}" = 1 ]; then
    export RUSTFLAGS="${RUSTFLAGS:-} -C target-cpu=native"
    export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-target/native}"
fi

setup() {
    if [ ! -x .venv/bin/python ]; then
        python3 -m venv .venv
    fi
    # shellcheck disable=SC1091
    . .venv/bin/activate
    echo "== setup: Python packages (first time ~1-2 min)"
    python -m pip install -q --upgrade pip
    python -m pip install -q "maturin>=1.9.4,<2"
    # Builds the Rust extension in release mode and installs the package
    # with its test and dask extras. pip's per-package lines go to a log,
    # shown only if the step fails.
    echo "== setup: Rust extension, release build (fresh clone ~3 min on 2 cores; then seconds)"
    local log=.venv/setup.log
    if ! maturin develop --release -q -E test,dask >"$log" 2>&1; then
        cat "$log" >&2
        echo "setup failed (log above, also in $log)" >&2
        exit 1
    fi
}

cmd="${1:-}"
case "$cmd" in
    demo)
        setup
        shift
        granseg demo "$@"
        ;;
    test)
        # The report test opens the HTML in headless Chromium (Debian's
        # package); CI machines are fresh, so install it there when possible.
        # The DEM tests run a short LAMMPS job (Debian's lammps package); same.
        if [ -n "${CI:-}" ] && { ! command -v chromium >/dev/null 2>&1 || ! command -v lmp >/dev/null 2>&1; } \
            && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
            (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium lammps >/dev/null) \
                || echo "warning: could not install chromium and lammps; the browser and LAMMPS tests will be skipped" >&2
        fi
        setup
        shift
        echo "== cargo test: pure Rust core, no Python (fresh clone ~1 min to build the tests)"
        cargo test --release -q
        echo "== ruff"
        ruff check python tests benches examples
        echo "== pytest: every Python test (~15 min on 2 cores)"
        python -m pytest -q "$@"
        ;;
    bench)
        setup
        shift
        # the release profile (not cargo's separate `bench` one): the crate and its
        # dependencies built for the demo and the tests are reused, not rebuilt
        cargo bench --profile release --bench solver -- --noplot
        python benches/compare_scipy.py
        ;;
    *)
        echo "usage: ./dev.sh demo | test | bench" >&2
        exit 2
        ;;
esac
