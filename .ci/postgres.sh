#!/usr/bin/env bash
# A throwaway PostgreSQL server on loopback for the history tests (docs/history.md).
#   eval "$(bash .ci/postgres.sh start)"   # prints the two export lines
#   bash .ci/postgres.sh stop "$EASYCALIB_TEST_POSTGRES_DATA"
# Installs Debian's PostgreSQL when it is missing (root only). initdb refuses
# root, so as root the server runs as the `postgres` user.
set -euo pipefail
PORT="${EASYCALIB_TEST_POSTGRES_PORT:-55432}"

pgbin() { ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1; }
as_owner() { if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }

case "${1:-}" in
start)
    if [ -z "$(pgbin)" ]; then
        if [ "$(id -u)" != 0 ]; then
            echo "PostgreSQL is not installed: apt-get install postgresql (as root)" >&2
            exit 1
        fi
        echo "installing PostgreSQL from Debian's packages" >&2
        DEBIAN_FRONTEND=noninteractive apt-get update -qq >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >&2
    fi
    BIN="$(pgbin)"
    DATA="$(mktemp -d /tmp/easycalib-pg.XXXXXX)"
    if [ "$(id -u)" = 0 ]; then chown postgres "$DATA"; fi
    as_owner "$BIN/initdb" -D "$DATA/data" -A trust -U postgres >/dev/null
    # Loopback only; the socket in the temp folder, not /var/run.
    as_owner "$BIN/pg_ctl" -D "$DATA/data" -l "$DATA/server.log" -w \
        -o "-c listen_addresses=127.0.0.1 -p $PORT -k $DATA -c fsync=off" start >&2
    echo "export EASYCALIB_TEST_POSTGRES_URL=postgres://postgres@127.0.0.1:$PORT/postgres"
    echo "export EASYCALIB_TEST_POSTGRES_DATA=$DATA"
    ;;
stop)
    DATA="${2:?the data folder printed by start}"
    as_owner "$(pgbin)/pg_ctl" -D "$DATA/data" -m fast -w stop >&2 || true
    rm -rf "$DATA"
    ;;
*)
    echo "usage: $0 start | stop DATA_DIR" >&2
    exit 2
    ;;
esac
