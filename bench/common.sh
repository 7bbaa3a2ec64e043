# Shared by the bench/*.sh scripts (sourced): paths, machine line, and run(), which times the
# best of $REPEAT runs of vdbrecon on the bunny scans and scores the mesh against the zippered
# reference. Expects BIN and OUT to be set by the caller.
DATA=../shared/data
BUNNY=$DATA/stanford_bunny/bun_scans_aligned.ply
GT=$DATA/stanford_bunny/bun_zipper_gt.ply
REPEAT=${REPEAT:-3}
mkdir -p "$OUT"
[ -f "$BUNNY" ] || { echo "bench: $BUNNY not found (needs ../shared/data)"; exit 1; }

machine_line() {
  echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2/1048576}' /proc/meminfo), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
  echo "commit: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)  date: $(date -u +%F)"
}

# better NEW BEST: whether the time NEW beats BEST (true when there is no BEST yet).
better() {
  [ -z "$2" ] || awk -v a="$1" -v b="$2" 'BEGIN {exit !(a < b)}'
}

# best_of LOG COMMAND...: runs COMMAND $REPEAT times under /usr/bin/time; sets WALL (s) and
# RSS (MB) of the fastest run and leaves its stderr in LOG.
best_of() {
  local log=$1 best=""; shift
  for ((k = 0; k < REPEAT; ++k)); do
    /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "$@" 2>"$OUT/try.log" >/dev/null
    read -r w r < "$OUT/time.txt"
    if better "$w" "$best"; then best=$w; WALL=$w; RSS=$((r / 1024)); cp "$OUT/try.log" "$log"; fi
  done
}

# run LABEL THREADS ARGS...: leaves $OUT/LABEL.ply, $OUT/LABEL.THREADS.log (stderr of the best
# run), $OUT/LABEL.json (eval at tau 0.5 mm and 1 mm) and sets WALL (s) and RSS (MB).
run() {
  local label=$1 threads=$2; shift 2
  best_of "$OUT/$label.$threads.log" "$BIN" "$BUNNY" -o "$OUT/$label.ply" --threads "$threads" "$@"
  "$BIN" eval "$OUT/$label.ply" "$GT" --tau 0.0005,0.001 > "$OUT/$label.json"
}

# stage_times LOG NAME...: the named per-stage times from a run's stderr, '|'-separated.
stage_times() {
  local log=$1; shift
  /usr/bin/python3 -c 'import re,sys; t=dict((m[0].strip(), m[1]) for m in re.findall(r"([a-z ()]+) ([0-9.]+) s,", open(sys.argv[1]).read())); print("|".join(t.get(k, "-") for k in sys.argv[2:]))' "$log" "$@"
}
