"""`wosac-server methods`: who owns each leaderboard name, and the operator's override.

A method name belongs, per challenge, to the key that first submitted under it (a
key's own name is reserved for it); other keys get `403` for it. The operator can
list the names, give one to another key, or free it.
Exit codes: 0 ok, 1 nothing to do (unknown key or name), 2 usage error.
"""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone

NAME = "methods"
HELP = "List leaderboard names and their owning keys; reassign or free one (operator override)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .settings import add_data_dir_option

    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    actions = [sub.add_parser("list", help="every claimed name: challenge, method, owning key")]
    for action, text in (
        ("assign", "give a name to a key"),
        ("release", "free a name (the next key to use it owns it)"),
    ):
        p = sub.add_parser(action, help=text)
        p.add_argument("--challenge", default="sim_agents", choices=("sim_agents", "scenario_gen"))
        p.add_argument("--method", required=True)
        if action == "assign":
            p.add_argument("--key", required=True, help="the name of the key that gets it")
        actions.append(p)
    add_data_dir_option(parser, actions)


def run(args: argparse.Namespace) -> int:
    from . import jobs
    from .settings import operator_store

    _, store = operator_store(args.data_dir)
    if args.action == "list":
        for row in jobs.list_methods(store):
            claimed = datetime.fromtimestamp(row["claimed_at"], tz=timezone.utc).isoformat(timespec="seconds")
            print(f"{row['challenge']}\t{row['method']}\t{row['key_name'] or '(deleted key)'}\tsince {claimed}")
        return 0
    if args.action == "release":
        if jobs.method_owner(store, args.challenge, args.method) is None:
            print(f"wosac-server methods: nobody owns {args.method!r} on {args.challenge}", file=sys.stderr)
            return 1
        jobs.assign_method(store, args.challenge, args.method, None)
        print(f"released {args.method} ({args.challenge})")
        return 0
    key = store.fetchone("SELECT id FROM api_keys WHERE name = ?", (args.key,))
    if key is None:
        print(f"wosac-server methods: no key named {args.key!r}", file=sys.stderr)
        return 1
    jobs.assign_method(store, args.challenge, args.method, key["id"])
    print(f"{args.method} ({args.challenge}) now belongs to key {args.key}")
    return 0
