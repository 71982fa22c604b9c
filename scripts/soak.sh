#!/usr/bin/env bash
# `make soak`: the streaming scenarios of issue 17 against one local `fogcast serve`
# (started with --debug-raw-frames, so loadgen can compare encoded frames with raw ones),
# reports under out/soak/ (docs/loadtest.md, "Streaming scenarios and make soak"):
#
#   a. codec quality: one 640x360 viewer walking colonnade's camera loop, JPEG at the
#      default quality, then H.264 capped at each of SOAK_H264_KBPS ("150 300 450") kbit/s,
#      --raw-every 5, SOAK_QUALITY_S (60) s each; prints bytes per frame and PSNR of each
#      and the verdict: the cheapest H.264 run with at least JPEG's PSNR, bound 0.25x;
#   b. a slow client: one viewer asking for 960x540 JPEG at quality 95 reads at 1000
#      kbit/s among four small unthrottled viewers, SOAK_THROTTLE_S (300) s after a
#      SOAK_BASELINE_S (30) s baseline with all five on fast links; then the same at
#      SOAK_TIGHT_KBPS (250) for SOAK_TIGHT_S (120) s, a link the stream does not fit;
#      checks p95 latency < 500 ms, creep <= 1.2, unthrottled fps within 10 %;
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
# shellcheck source=scripts/lib/serve.sh
. "$(dirname "$0")/lib/serve.sh"
# shellcheck disable=SC2086 # SERVE_ARGS is a list of flags
start_server soak "$out" --debug-raw-frames --idle-timeout-s "$idle_timeout_s" ${SERVE_ARGS:-}
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

# Which scenarios run: SOAK_SCENARIOS, any of "quality throttled soak" (all by default).
scenarios=" ${SOAK_SCENARIOS:-quality throttled soak} "
wants() { [[ $scenarios == *" $1 "* ]]; }

# a. Codec quality: the same camera walk (each run starts at the same point of the loop),
#    JPEG at the server's default quality, then H.264 capped at each bitrate of
#    SOAK_H264_KBPS; the verdict is the cheapest H.264 run with at least JPEG's PSNR.
h264_kbps=${SOAK_H264_KBPS:-150 300 450}
if wants quality; then
loadgen quality-jpeg --viewers 1 --width 640 --height 360 --codec jpeg --raw-every 5 \
  --seconds "$quality_s" --window-s "$quality_s" --out "$out/quality-jpeg"
for kbps in $h264_kbps; do
  loadgen "quality-h264-$kbps" --viewers 1 --width 640 --height 360 --codec h264 --max-kbps "$kbps" \
    --raw-every 5 --seconds "$quality_s" --window-s "$quality_s" --out "$out/quality-h264-$kbps"
done
# shellcheck disable=SC2086 # the bitrates are a list
python3 - "$out" $h264_kbps <<'PY' | tee "$out/quality.txt" || failed+=("quality comparison")
import json, sys
out, ladder = sys.argv[1], sys.argv[2:]
def row(name):
    s = json.load(open(f"{out}/{name}/loadgen.json"))["points"][0]["summary"]
    q = s.get("quality") or {}
    return s["encoded_bytes_per_frame"], q.get("psnr_mean_db"), q.get("psnr_min_db"), q.get("compared", 0)
rows = {"jpeg": row("quality-jpeg")}
for k in ladder:
    rows[f"h264 {k} kbit/s"] = row(f"quality-h264-{k}")
for name, (b, mean, low, n) in rows.items():
    if mean is None:
        sys.exit(f"soak: no PSNR for {name} (is the server started with --debug-raw-frames?)")
    print(f"soak: {name:>16}: {b:8.0f} bytes/frame, PSNR mean {mean:.2f} dB, min {low:.2f} dB over {n} frames")
jb, jq = rows["jpeg"][0], rows["jpeg"][1]
for k in ladder:
    hb, hq = rows[f"h264 {k} kbit/s"][0], rows[f"h264 {k} kbit/s"][1]
    print(f"soak: H.264 at {k} kbit/s / JPEG: {hb / jb:.3f}x the bytes per frame, {hq - jq:+.2f} dB PSNR")
ok = [k for k in ladder if rows[f"h264 {k} kbit/s"][1] >= jq]
if not ok:
    sys.exit("soak: no H.264 run reached JPEG's PSNR")
k = ok[0]
ratio = rows[f"h264 {k} kbit/s"][0] / jb
print(f"soak: verdict: H.264 at {k} kbit/s has {ratio:.3f}x JPEG's bytes per frame at equal or better PSNR (bound 0.25)")
if ratio > 0.25:
    sys.exit("soak: H.264 is above 0.25x JPEG's bytes at equal PSNR")
PY
fi

# b. One slow client among four: its latency stays flat, the others keep their fps. The
#    throttled viewer asks for the heaviest stream (960x540 JPEG at quality 95) and the
#    others for small views of their own sizes; then the same at SOAK_TIGHT_KBPS (250),
#    a link narrower than that stream on a CPU renderer, where the adaptation must act.
if wants throttled; then
mix=960x540,256x144,240x136,272x154,224x126
loadgen throttled --viewers 5 --mix "$mix" --codec jpeg --quality 95 \
  --throttle-kbps 1000 --throttled 1 --baseline-s "$baseline_s" --seconds "$throttle_s" \
  --window-s "$(window_of "$throttle_s" 5)" \
  --check-latency-p95-ms 500 --check-creep 1.2 --check-fps-within 0.1 --out "$out/throttled"
tight_s=${SOAK_TIGHT_S:-120}
loadgen throttled-tight --viewers 5 --mix "$mix" --codec jpeg --quality 95 \
  --throttle-kbps "${SOAK_TIGHT_KBPS:-250}" --throttled 1 --baseline-s "$baseline_s" --seconds "$tight_s" \
  --window-s "$(window_of "$tight_s" 4)" \
  --check-latency-p95-ms 500 --check-creep 1.2 --check-fps-within 0.1 --out "$out/throttled-tight"

fi

# c. Soak: 16 churning viewers; memory, latency and sessions stay put.
if wants soak; then
loadgen soak --viewers 16 --width 256 --height 144 --codec h264 --churn-s "$churn_s" \
  --seconds "$soak_s" --window-s "$(window_of "$soak_s" 10)" \
  --check-memory-growth 0.1 --check-creep 1.2 --check-sessions --out "$out/soak"

fi

took=$(( $(date +%s) - started ))
if [ ${#failed[@]} -gt 0 ]; then
  echo "soak: FAILED after $took s: ${failed[*]} (reports in $out/)" >&2
  exit 1
fi
echo "soak: every scenario passed in $took s; reports in $out/{quality-*,throttled,throttled-tight,soak}/loadgen.md" >&2
