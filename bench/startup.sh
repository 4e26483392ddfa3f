#!/bin/sh
# Process start-up of hapticloud, against the floor of starting any process: the median wall
# time of `hapticloud --version` (dynamic loading of the program and every shared library it
# pulls in, static initialisers, CLI set-up) and of `true`, over RUNS runs each, interleaved.
# Usage: bench/startup.sh [BUILD_DIR [RUNS]]   (default build/release, 15 runs)
# Prints medians in milliseconds, their ratio, and the shared libraries the program loads.
set -eu
build=${1:-build/release}
runs=${2:-15}
app="$build/apps/hapticloud/hapticloud"
[ -x "$app" ] || { echo "startup.sh: $app is missing; build the release preset first" >&2; exit 2; }
now_us() { date +%s%6N; }
app_t=""; true_t=""
i=0
while [ "$i" -lt "$runs" ]; do
  s=$(now_us); "$app" --version >/dev/null; e=$(now_us); app_t="$app_t $((e - s))"
  s=$(now_us); true; /bin/true; e=$(now_us); true_t="$true_t $((e - s))"
  i=$((i + 1))
done
median() { printf '%s\n' $1 | sort -n | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
ma=$(median "$app_t"); mt=$(median "$true_t")
echo "hapticloud --version: median $(awk "BEGIN {printf \"%.1f\", $ma / 1000}") ms over $runs runs"
echo "/bin/true:            median $(awk "BEGIN {printf \"%.1f\", $mt / 1000}") ms"
echo "ratio:                $(awk "BEGIN {printf \"%.0f\", $ma / ($mt > 0 ? $mt : 1)}")"
echo "shared libraries loaded: $(ldd "$app" | wc -l) (direct: $(readelf -d "$app" | grep -c NEEDED))"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
