#!/usr/bin/env bash
# `make soak`: the streaming scenarios of issue 17 against one local `fogcast serve`
# (started with --debug-raw-frames, so loadgen can compare encoded frames with raw ones),
# reports under out/soak/ (docs/loadtest.md, "Streaming scenarios and make soak"):
#
#   a. codec quality: one 640x360 viewer, JPEG then H.264, --raw-every 5, SOAK_QUALITY_S
#      (60) s each; prints bytes per frame and PSNR of both and their ratio;
#   b. a slow client: 4 unthrottled H.264 viewers at 320x180 and one reading at 1000
#      kbit/s, SOAK_THROTTLE_S (300) s after a SOAK_BASELINE_S (30) s baseline of the
#      four alone; checks p95 latency < 500 ms, creep <= 1.2, unthrottled fps within 10 %;
#   c. soak: 16 H.264 viewers at 256x144, each reopening its session every SOAK_CHURN_S
#      (30) s, for SOAK_S (600) s; checks server memory growth <= 10 %, creep <= 1.2 and
#      that every session opened was counted and closed.
#
# Every scenario runs even when an earlier one fails; the exit status is 1 if any failed.
# A short version for CI: SOAK_QUALITY_S=10 SOAK_THROTTLE_S=30 SOAK_BASELINE_S=10 SOAK_S=60
# SOAK_CHURN_S=10. Other knobs: SOAK_WINDOW_S (the window for creep and memory: a fifth of
# scenario b, a tenth of c), SOAK_IDLE_TIMEOUT_S (30: the server closes sessions without
# poses after this; loadgen sends SOAK_POSE_HZ, 10, poses a second), SCENE (colonnade),
# SERVE_ARGS, OUT (out/soak), FOGCAST (./target/release/fogcast).
set -euo pipefail

bin=${FOGCAST:-./target/release/fogcast}
scene=${SCENE:-colonnade}
out=${OUT:-out/soak}
quality_s=${SOAK_QUALITY_S:-60}
throttle_s=${SOAK_THROTTLE_S:-300}
baseline_s=${SOAK_BASELINE_S:-30}
soak_s=${SOAK_S:-600}
churn_s=${SOAK_CHURN_S:-30}
idle_timeout_s=${SOAK_IDLE_TIMEOUT_S:-30}
pose_hz=${SOAK_POSE_HZ:-10}
started=$(date +%s)

[ -x "$bin" ] || { echo "soak: $bin not found; run \`make build\` first" >&2; exit 1; }
mkdir -p "$out"
server_out="$out/server.stdout"
server_log="$out/server.log"
# shellcheck disable=SC2086 # SERVE_ARGS is a list of flags
"$bin" serve --scene "$scene" --addr 127.0.0.1 --port 0 --debug-raw-frames --idle-timeout-s "$idle_timeout_s" ${SERVE_ARGS:-} >"$server_out" 2>"$server_log" &
server=$!
stop_server() {
  if kill -0 "$server" 2>/dev/null; then
    kill -TERM "$server" 2>/dev/null || true
    for _ in $(seq 1 100); do
      kill -0 "$server" 2>/dev/null || break
      sleep 0.1
    done
    kill -KILL "$server" 2>/dev/null || true
  fi
  wait "$server" 2>/dev/null || true
}
trap stop_server EXIT
trap 'exit 130' INT TERM

url=
for _ in $(seq 1 1200); do
  if ! kill -0 "$server" 2>/dev/null; then
    echo "soak: the server exited during start-up; its log ($server_log):" >&2
    tail -n 20 "$server_log" >&2
    exit 1
  fi
  url=$(grep -o 'http://[0-9.]*:[0-9]*' "$server_out" | head -n 1 || true)
  [ -n "$url" ] && break
  sleep 0.1
done
[ -n "$url" ] || { echo "soak: the server did not start listening within 120 s; see $server_log" >&2; exit 1; }
ws="ws://${url#http://}/ws"
echo "soak: server at $url; reports in $out/" >&2

# A window a fifth (b) or a tenth (c) of the scenario, unless SOAK_WINDOW_S says.
window_of() { echo "${SOAK_WINDOW_S:-$(( $1 / $2 > 0 ? $1 / $2 : 1 ))}"; }

failed=()
loadgen() {
  local name=$1
  shift
  echo "soak: --- $name ---" >&2
  if ! "$bin" loadgen --url "$ws" --pose-hz "$pose_hz" "$@"; then
    failed+=("$name")
  fi
}

# a. Codec quality: the same view, JPEG then H.264.
for codec in jpeg h264; do
  loadgen "quality-$codec" --viewers 1 --width 640 --height 360 --codec "$codec" --raw-every 5 \
    --seconds "$quality_s" --window-s "$quality_s" --out "$out/quality-$codec"
done
python3 - "$out" <<'PY' || failed+=("quality comparison")
import json, sys
out = sys.argv[1]
rows = {}
for codec in ("jpeg", "h264"):
    s = json.load(open(f"{out}/quality-{codec}/loadgen.json"))["points"][0]["summary"]
    q = s.get("quality") or {}
    rows[codec] = (s["encoded_bytes_per_frame"], q.get("psnr_mean_db"), q.get("psnr_min_db"), q.get("compared", 0))
for codec, (b, mean, low, n) in rows.items():
    print(f"soak: {codec:>4}: {b:8.0f} bytes/frame, PSNR mean {mean if mean is None else round(mean, 2)} dB, "
          f"min {low if low is None else round(low, 2)} dB over {n} frames")
(jb, jq, _, _), (hb, hq, _, _) = rows["jpeg"], rows["h264"]
if jb and hb and jq is not None and hq is not None:
    print(f"soak: H.264/JPEG: {hb / jb:.3f}x the bytes per frame, {hq - jq:+.2f} dB PSNR")
else:
    sys.exit("soak: no PSNR for one of the codecs (is the server started with --debug-raw-frames?)")
PY

# b. One slow client among four: its latency stays flat, the others keep their fps.
loadgen throttled --viewers 5 --width 320 --height 180 --codec h264 \
  --throttle-kbps 1000 --throttled 1 --baseline-s "$baseline_s" --seconds "$throttle_s" \
  --window-s "$(window_of "$throttle_s" 5)" \
  --check-latency-p95-ms 500 --check-creep 1.2 --check-fps-within 0.1 --out "$out/throttled"

# c. Soak: 16 churning viewers; memory, latency and sessions stay put.
loadgen soak --viewers 16 --width 256 --height 144 --codec h264 --churn-s "$churn_s" \
  --seconds "$soak_s" --window-s "$(window_of "$soak_s" 10)" \
  --check-memory-growth 0.1 --check-creep 1.2 --check-sessions --out "$out/soak"

took=$(( $(date +%s) - started ))
if [ ${#failed[@]} -gt 0 ]; then
  echo "soak: FAILED after $took s: ${failed[*]} (reports in $out/)" >&2
  exit 1
fi
echo "soak: every scenario passed in $took s; reports in $out/{quality-jpeg,quality-h264,throttled,soak}/loadgen.md" >&2
