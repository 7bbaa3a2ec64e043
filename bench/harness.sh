# Shared by bench/compare.sh and bench/scaling.sh (sourced from the repository root with OUT
# set): installs the Debian packages the peers need, runs a command under /usr/bin/time, scores
# its mesh with `vdbrecon eval` and appends one tab-separated row per run to $ROWS (emptied
# here) for bench/table.py.
BIN=${BIN:-build/vdbrecon}
source bench/common.sh       # DATA, BUNNY, GT, machine_line; creates OUT
PY=/usr/bin/python3          # Debian's interpreter: numpy and open3d live there
QUICK=${QUICK:-0}            # 1: a fast check of the harness, not numbers to keep
if [ "$QUICK" = 1 ]; then SAMPLES=${SAMPLES:-200000}; fi
SAMPLES=${SAMPLES:-1000000}  # eval samples per mesh
TIMEOUT=${TIMEOUT:-1200}     # seconds per run before it is killed and reported as a timeout
TAUS=0.0005,0.001
ROWS=$OUT/rows.tsv
[ -x "$BIN" ] || { echo "bench: no vdbrecon binary at '$BIN' (set BIN=path/to/vdbrecon)" >&2; exit 1; }
: >"$ROWS"

# ensure_packages PKG...: apt-get installs the missing ones (as root, or with sudo).
ensure_packages() {
  local missing=() p sudo=""
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  ((${#missing[@]})) || return 0
  echo "bench: installing ${missing[*]}" >&2
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

load_line() { echo "load average: $(cut -d' ' -f1-3 /proc/loadavg) ($(nproc) cores)"; }

# timed LOG CMD...: runs CMD (stdout and stderr to LOG) under /usr/bin/time and `timeout`; sets
# RC (exit status, 124 on timeout), WALL and CPU (user + system, seconds) and RSS (peak, MB).
timed() {
  local log=$1 user sys rss; shift
  RC=0
  /usr/bin/time -f "%e %U %S %M" -o "$OUT/time.txt" timeout "$TIMEOUT" "$@" >"$log" 2>&1 || RC=$?
  read -r WALL user sys rss < <(tail -n 1 "$OUT/time.txt")
  CPU=$(awk -v u="$user" -v s="$sys" 'BEGIN {printf "%.2f", u + s}')
  RSS=$((rss / 1024))
}

# score MESH JSON GT [MASK MASK_DISTANCE]: `vdbrecon eval` of MESH against GT (at TAUS, SAMPLES
# samples; completeness only where GT lies within MASK_DISTANCE of a MASK point), or, without
# GT, the mesh against itself for its topology alone.
score() {
  local mesh=$1 json=$2 gt=$3 mask=${4:-} dist=${5:-}
  if [ -z "$gt" ]; then
    "$BIN" eval "$mesh" "$mesh" --samples 1000 >"$json"
  elif [ -n "$mask" ]; then
    "$BIN" eval "$mesh" "$gt" --tau "$TAUS" --samples "$SAMPLES" --mask-points "$mask" \
      --mask-distance "$dist" >"$json"
  else
    "$BIN" eval "$mesh" "$gt" --tau "$TAUS" --samples "$SAMPLES" >"$json"
  fi
}

# add_row DATASET METHOD SETTING LOG JSON [EXTRA]: appends the last timed run to $ROWS; the status
# is "ok", "exit N" or "timeout", JSON is "-" when there is no mesh to score.
add_row() {
  local status=ok
  if [ "$RC" -eq 124 ]; then status=timeout; elif [ "$RC" -ne 0 ]; then status="exit $RC"; fi
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$1" "$2" "$3" "$status" "$WALL" "$CPU" \
    "$RSS" "$4" "$5" "${6:-}" >>"$ROWS"
}
