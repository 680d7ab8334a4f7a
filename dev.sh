#!/usr/bin/env bash
# granseg's two commands (and a few helpers). Needs only python3 (>= 3.11)
# and a Rust toolchain; everything else is installed into ./.venv.
#
#   ./dev.sh demo     set up, then run the demo on the embedded data
#   ./dev.sh test     set up, then run every test (Rust and Python)
#   ./dev.sh bench    set up, then run the benchmarks behind BENCHMARKS.md
set -euo pipefail
cd "$(dirname "$0")"

setup() {
    if [ ! -x .venv/bin/python ]; then
        python3 -m venv .venv
    fi
    # shellcheck disable=SC1091
    . .venv/bin/activate
    python -m pip install -q --upgrade pip
    python -m pip install -q "maturin>=1.9.4,<2"
    # Builds the Rust extension in release mode and installs the package
    # with its test and dask extras.
    maturin develop --release -q -E test,dask
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
        echo "== cargo test (pure Rust core, no Python)"
        cargo test --release -q
        echo "== ruff"
        ruff check python tests benches
        echo "== pytest"
        python -m pytest -q "$@"
        ;;
    bench)
        setup
        shift
        cargo bench --bench solver -- --noplot
        python benches/compare_scipy.py
        ;;
    *)
        echo "usage: ./dev.sh demo | test | bench" >&2
        exit 2
        ;;
esac
