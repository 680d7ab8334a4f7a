#!/usr/bin/env bash
# Wall time of ./dev.sh test's set-up and build phases on fresh clones of the given revisions:
# a new venv, pip (from whatever wheel cache the machine has), the release build of the
# extension, cargo test, ruff and pytest's collection (no test selected). Also counts the rayon
# builds left in target/release/deps (1 = the extension and cargo test share their dependencies).
#
#   benches/time_setup.sh d5a6270 HEAD
set -u
repo=$(cd "$(dirname "$0")/.." && pwd)
for rev in "$@"; do
  d=$(mktemp -d)/clone
  git clone -q "$repo" "$d" && (cd "$d" && git checkout -q "$rev")
  load0=$(cut -d' ' -f1 /proc/loadavg)
  start=$(date +%s.%N)
  (cd "$d" && ./dev.sh test -k no_test_has_this_name > "$d.log" 2>&1)
  end=$(date +%s.%N)
  load1=$(cut -d' ' -f1 /proc/loadavg)
  n=$(ls "$d/target/release/deps" | grep -c '^librayon-.*\.rlib$')
  printf '%s %.1f s, load %s -> %s, rayon builds: %s (log: %s.log)\n' "$rev" "$(echo "$end - $start" | bc)" \
    "$load0" "$load1" "$n" "$d"
done
