#!/usr/bin/env python3
"""Generate wosac_eval/protos/*_pb2.py (and their *_pb2.pyi type stubs) from protos/wosac_eval/protos/*.proto.

Usage (from anywhere; paths are resolved from this script's location):
    python scripts/gen_protos.py          # regenerate the committed modules
    python scripts/gen_protos.py --check  # exit 1 if the committed modules are stale

Uses the protoc bundled with grpcio-tools, at the exact version pinned in the
`test` extra of pyproject.toml: the generated code embeds the protoc version
(and a matching protobuf runtime check), so another grpcio-tools version gives
different bytes and `--check` reports them as stale.
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
PROTO_ROOT = REPO_ROOT / "protos"
PROTO_DIR = PROTO_ROOT / "wosac_eval" / "protos"
OUTPUT_ROOT = REPO_ROOT  # modules land in REPO_ROOT/wosac_eval/protos/
GENERATED_DIR = OUTPUT_ROOT / "wosac_eval" / "protos"


def proto_files() -> list[Path]:
    """The .proto sources, sorted so generation order is stable."""
    return sorted(PROTO_DIR.glob("*.proto"))


def run_protoc(out_root: Path) -> None:
    """Run the bundled protoc on every source, writing *_pb2.py and *_pb2.pyi under out_root.

    The .pyi stubs give the type checker the message classes, which the .py modules build at import time.
    """
    from grpc_tools import protoc  # test-extra dependency; imported lazily

    sources = [str(p.relative_to(PROTO_ROOT)) for p in proto_files()]
    args = ["protoc", f"-I{PROTO_ROOT}", f"--python_out={out_root}", f"--pyi_out={out_root}", *sources]
    status = protoc.main(args)
    if status != 0:
        raise SystemExit(f"protoc failed with status {status}: {' '.join(args)}")


def generated_names(directory: Path) -> set[str]:
    """Names of the generated *_pb2.py modules and *_pb2.pyi stubs in directory."""
    return {p.name for pattern in ("*_pb2.py", "*_pb2.pyi") for p in directory.glob(pattern)}


def stale_modules(fresh_dir: Path) -> list[str]:
    """Modules that differ between a fresh generation and the committed copy."""
    fresh, committed = generated_names(fresh_dir), generated_names(GENERATED_DIR)
    problems = [f"{name}: missing from wosac_eval/protos" for name in sorted(fresh - committed)]
    problems += [f"{name}: has no .proto source" for name in sorted(committed - fresh)]
    for name in sorted(fresh & committed):
        if not filecmp.cmp(fresh_dir / name, GENERATED_DIR / name, shallow=False):
            problems.append(f"{name}: differs from freshly generated code")
    return problems


def installed_grpcio_tools() -> str:
    """The installed grpcio-tools version, for error messages."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("grpcio-tools")
    except PackageNotFoundError:
        return "not installed"


def check() -> int:
    """Regenerate into a temp dir and compare; 0 when up to date, 1 otherwise."""
    with tempfile.TemporaryDirectory() as tmp:
        run_protoc(Path(tmp))
        problems = stale_modules(Path(tmp) / "wosac_eval" / "protos")
    if not problems:
        print(f"wosac_eval/protos: {len(proto_files())} generated modules are up to date")
        return 0
    print("wosac_eval/protos is stale:", *problems, sep="\n  ", file=sys.stderr)
    print(
        f"(grpcio-tools {installed_grpcio_tools()} installed; use the version pinned in"
        " pyproject.toml's test extra, then run scripts/gen_protos.py)",
        file=sys.stderr,
    )
    return 1


def generate() -> int:
    """Regenerate the committed modules in place."""
    run_protoc(OUTPUT_ROOT)
    print(f"generated {len(proto_files())} modules into {GENERATED_DIR.relative_to(REPO_ROOT)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the committed modules are stale")
    args = parser.parse_args(argv)
    return check() if args.check else generate()


if __name__ == "__main__":
    sys.exit(main())
