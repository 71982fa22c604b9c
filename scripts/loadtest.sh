#!/usr/bin/env bash
# `make loadtest`: starts `fogcast serve` on a free loopback port, waits for /healthz,
# runs the default `fogcast loadgen` sweep (1 to 16 viewers, all at one size) into
# out/loadtest/, then the mixed-size sweep (`--sweep mixed`: a third of the viewers at
# each of 320x180, 480x270 and 640x360) into out/loadtest/mixed/, and stops the server
# whatever happens (trap). docs/loadtest.md explains the numbers.
#
# Knobs (environment): SCENE (colonnade), LOADTEST_VIEWERS (1,2,4,8,12,16),
# LOADTEST_SECONDS (20), LOADGEN_ARGS (more loadgen flags, first sweep),
# LOADTEST_MIXED (1; 0 skips the mixed sweep), MIXED_ARGS (more loadgen flags, mixed
# sweep), SERVE_ARGS (more serve flags), OUT (out/loadtest), FOGCAST
# (./target/release/fogcast).
set -euo pipefail

bin=${FOGCAST:-./target/release/fogcast}
scene=${SCENE:-colonnade}
out=${OUT:-out/loadtest}
viewers=${LOADTEST_VIEWERS:-1,2,4,8,12,16}
seconds=${LOADTEST_SECONDS:-20}
started=$(date +%s)

[ -x "$bin" ] || { echo "loadtest: $bin not found; run \`make build\` first" >&2; exit 1; }
mkdir -p "$out"
# shellcheck source=scripts/lib/serve.sh
. "$(dirname "$0")/lib/serve.sh"
# shellcheck disable=SC2086 # SERVE_ARGS is a list of flags
start_server loadtest "$out" ${SERVE_ARGS:-}
hostport=${url#http://}

healthz() {
  if command -v curl >/dev/null 2>&1; then
    curl -fsS --max-time 5 "$url/healthz"
  else
    exec 3<>"/dev/tcp/${hostport%:*}/${hostport#*:}" &&
      printf 'GET /healthz HTTP/1.1\r\nHost: %s\r\nConnection: close\r\n\r\n' "$hostport" >&3 &&
      grep -q '"status":"ok"' <&3 && echo '{"status":"ok"}'
  fi
}
health=
for _ in $(seq 1 300); do
  health=$(healthz 2>/dev/null) && break
  sleep 0.2
done
[ -n "$health" ] || { echo "loadtest: $url/healthz never answered; see $server_log" >&2; exit 1; }
echo "loadtest: server at $url (started in $(( $(date +%s) - started )) s): $health" >&2

# shellcheck disable=SC2086 # LOADGEN_ARGS is a list of flags
"$bin" loadgen --url "ws://$hostport/ws" --viewers "$viewers" --seconds "$seconds" --out "$out" ${LOADGEN_ARGS:-}
reports="$out/loadgen.md"
if [ "${LOADTEST_MIXED:-1}" != 0 ]; then
  # shellcheck disable=SC2086 # MIXED_ARGS is a list of flags
  "$bin" loadgen --url "ws://$hostport/ws" --sweep mixed --seconds "$seconds" --out "$out/mixed" ${MIXED_ARGS:-}
  reports="$reports, $out/mixed/loadgen.md"
fi
echo "loadtest: done in $(( $(date +%s) - started )) s; reports: $reports" >&2
