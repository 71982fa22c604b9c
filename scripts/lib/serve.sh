# Sourced by scripts/loadtest.sh and scripts/soak.sh: start `fogcast serve` on a free
# loopback port, stop it whatever happens (trap), and wait until it listens.
#
#   start_server NAME OUT_DIR [serve flags...]
#
# NAME prefixes messages; the server's stdout and log go to OUT_DIR/server.{stdout,log};
# `bin` and `scene` must be set. Sets `server` (its pid) and `url` (http://127.0.0.1:PORT).

start_server() {
  local name=$1 dir=$2
  shift 2
  server_out="$dir/server.stdout"
  server_log="$dir/server.log"
  "$bin" serve --scene "$scene" --addr 127.0.0.1 --port 0 "$@" >"$server_out" 2>"$server_log" &
  server=$!
  trap stop_server EXIT
  trap 'exit 130' INT TERM
  # The server prints "fogcast serving http://127.0.0.1:PORT ..." once it listens (after
  # building the scene's BVH and pipelines).
  url=
  for _ in $(seq 1 1200); do
    if ! kill -0 "$server" 2>/dev/null; then
      echo "$name: the server exited during start-up; its log ($server_log):" >&2
      tail -n 20 "$server_log" >&2
      exit 1
    fi
    url=$(grep -o 'http://[0-9.]*:[0-9]*' "$server_out" | head -n 1 || true)
    [ -n "$url" ] && break
    sleep 0.1
  done
  [ -n "$url" ] || { echo "$name: the server did not start listening within 120 s; see $server_log" >&2; exit 1; }
}

stop_server() {
  if kill -0 "$server" 2>/dev/null; then
    kill -TERM "$server" 2>/dev/null || true
    # Graceful shutdown closes every session; give it 10 s before forcing.
    for _ in $(seq 1 100); do
      kill -0 "$server" 2>/dev/null || break
      sleep 0.1
    done
    kill -KILL "$server" 2>/dev/null || true
  fi
  wait "$server" 2>/dev/null || true
}
