"""`wosac-server keys`: create, list and revoke API keys of the scoring service.

Keys are stored salted and hashed in the service database (`WOSAC_DB_URL`, default
the SQLite file in `WOSAC_DATA_DIR`); `create` prints the new key once, on stdout.
Exit codes: 0 ok, 1 nothing to do (name taken, unknown key), 2 usage error.
"""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone

NAME = "keys"
HELP = "Manage API keys of the scoring service (create prints a new key)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .settings import add_data_dir_option

    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    create = sub.add_parser("create", help="create a key and print it")
    create.add_argument("--name", required=True, help="owner / method name shown on the leaderboard")
    create.add_argument("--max-concurrent", type=int, help="unfinished submissions at a time")
    create.add_argument("--max-daily", type=int, help="submissions per 24 h")
    create.add_argument("--max-daily-bytes", type=int, help="uploaded bytes per 24 h")
    listing = sub.add_parser("list", help="list keys (never the secrets)")
    revoke = sub.add_parser("revoke", help="revoke a key by name")
    revoke.add_argument("--name", required=True)
    add_data_dir_option(parser, [create, listing, revoke])


def run(args: argparse.Namespace) -> int:
    from . import auth
    from .settings import operator_store

    settings, store = operator_store(args.data_dir)
    if args.action == "create":
        import re

        from .auth import METHOD_PATTERN

        if not re.match(METHOD_PATTERN, args.name):
            print(
                f"wosac-server keys: the name {args.name!r} must match {METHOD_PATTERN} "
                "(it is the default method name on the leaderboard)",
                file=sys.stderr,
            )
            return 2
        limits = {
            "max_concurrent": args.max_concurrent or settings.default_max_concurrent,
            "max_daily": args.max_daily or settings.default_max_daily,
            "max_daily_bytes": args.max_daily_bytes or settings.default_max_daily_bytes,
        }
        if min(limits.values()) < 1:
            print("wosac-server keys: limits must be positive", file=sys.stderr)
            return 2
        try:
            key = auth.create_key(store, args.name, **limits)
        except ValueError as exc:
            print(f"wosac-server keys: {exc}", file=sys.stderr)
            return 1
        print(key)
        return 0
    if args.action == "list":
        for row in auth.list_keys(store):
            created = datetime.fromtimestamp(row["created_at"], tz=timezone.utc).isoformat(timespec="seconds")
            status = "revoked" if row["revoked_at"] else "active"
            print(
                f"{row['name']}\t{row['id']}\t{status}\tcreated {created}\tconcurrent {row['max_concurrent']}"
                f"\tdaily {row['max_daily']}\tbytes/day {row['max_daily_bytes']}"
            )
        return 0
    if not auth.revoke_key(store, args.name):
        print(f"wosac-server keys: no active key named {args.name!r}", file=sys.stderr)
        return 1
    print(f"revoked {args.name}")
    return 0
