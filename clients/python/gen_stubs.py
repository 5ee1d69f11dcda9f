#!/usr/bin/env python3
"""Generates the gRPC stubs of proto/proxima/v1/proxima.proto into a package folder (proxima/_pb).

Used by CMake (clients/python/CMakeLists.txt, the build tree's package) and by setup.py (pip
installs), so both lay out the same modules: `proxima._pb.proxima_pb2` (messages, with a .pyi
for type checkers) and `proxima._pb.proxima_pb2_grpc` (the service stub).

Why protoc and /usr/bin/grpc_python_plugin, not `python3 -m grpc_tools.protoc`: Debian 12's
python3-grpc-tools (1.14.1) bundles protoc 3.5.1, which rejects the proto's proto3 `optional`
fields ("Explicit 'optional' labels are disallowed"). Debian's protoc (3.21, protobuf-compiler)
with the plugin from protobuf-compiler-grpc produces stubs that work with its python3-grpcio
(1.51) and python3-protobuf (3.21).

    gen_stubs.py --out DIR/proxima/_pb [--proto FILE] [--protoc PROTOC] [--plugin PLUGIN]
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Optional, Sequence

HERE = Path(__file__).resolve().parent
DEFAULT_PROTO = HERE.parent.parent / "proto" / "proxima" / "v1" / "proxima.proto"


def generate(out: Path, proto: Optional[Path] = None, protoc: Optional[str] = None,
             plugin: Optional[str] = None) -> None:
    """Writes proxima_pb2.py, proxima_pb2.pyi, proxima_pb2_grpc.py and __init__.py into `out`."""
    proto = Path(proto or os.environ.get("PROXIMA_PROTO") or DEFAULT_PROTO)
    protoc = protoc or os.environ.get("PROXIMA_PROTOC") or shutil.which("protoc") or "protoc"
    plugin = (plugin or os.environ.get("PROXIMA_GRPC_PYTHON_PLUGIN") or
              shutil.which("grpc_python_plugin") or "/usr/bin/grpc_python_plugin")
    if not proto.is_file():
        raise RuntimeError(f"no proto at {proto} (build from the repository, or set PROXIMA_PROTO)")
    out.mkdir(parents=True, exist_ok=True)
    cmd = [protoc, f"--proto_path={proto.parent}", f"--python_out={out}", f"--pyi_out={out}",
           f"--grpc_python_out={out}", f"--plugin=protoc-gen-grpc_python={plugin}", str(proto)]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True)
    except FileNotFoundError as e:
        raise RuntimeError(f"cannot run {protoc} (Debian package protobuf-compiler): {e}") from e
    if p.returncode != 0:
        raise RuntimeError(f"generating the Python stubs failed: {' '.join(cmd)}\n{p.stderr}")
    # The plugin imports the messages as a top-level module; inside the package it is a sibling.
    grpc_module = out / "proxima_pb2_grpc.py"
    text = grpc_module.read_text()
    fixed = re.sub(r"^import proxima_pb2 as ", "from . import proxima_pb2 as ", text, flags=re.M)
    if fixed == text:
        raise RuntimeError(f"{grpc_module}: no 'import proxima_pb2' line to make relative")
    grpc_module.write_text(fixed)
    (out / "__init__.py").write_text('"""Generated from proxima.proto at build time."""\n')


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--proto", type=Path)
    parser.add_argument("--protoc")
    parser.add_argument("--plugin")
    args = parser.parse_args(argv)
    try:
        generate(args.out, args.proto, args.protoc, args.plugin)
    except RuntimeError as e:
        print(f"gen_stubs: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
