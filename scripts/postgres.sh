#!/usr/bin/env bash
# A throwaway PostgreSQL server for the station's database tests (tests/station/test_store.py).
#   scripts/postgres.sh start DIR PORT   initdb in DIR, start on 127.0.0.1:PORT, print its URL
#   scripts/postgres.sh stop DIR         stop it
# Installs Debian's postgresql package first when it is missing and we are root with apt-get.
# PostgreSQL refuses to run as root: as root the server runs as the 'postgres' user.
set -euo pipefail
action=${1:?start DIR PORT | stop DIR}
dir=${2:?data directory}
bindir=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1 || true)
if [ -z "$bindir" ] && [ "$action" = start ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  echo "installing postgresql for the database tests" >&2
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null) >&2
  bindir=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1 || true)
fi
[ -n "$bindir" ] || { echo "PostgreSQL is not installed (and cannot be installed here)" >&2; exit 3; }
as_server() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}
case "$action" in
  start)
    port=${3:?port}
    mkdir -p "$dir"
    [ "$(id -u)" = 0 ] && chown postgres "$dir"
    as_server "$bindir/initdb" -D "$dir" -A trust -U evp >/dev/null
    as_server "$bindir/pg_ctl" -D "$dir" -l "$dir/server.log" -w -t 60 \
      -o "-p $port -k $dir -c listen_addresses=127.0.0.1 -c fsync=off" start >/dev/null
    as_server "$bindir/createdb" -h 127.0.0.1 -p "$port" -U evp evp
    echo "postgresql://evp@127.0.0.1:$port/evp"
    ;;
  stop)
    as_server "$bindir/pg_ctl" -D "$dir" -m immediate -w stop >/dev/null
    ;;
  *) echo "unknown action $action" >&2; exit 2 ;;
esac
