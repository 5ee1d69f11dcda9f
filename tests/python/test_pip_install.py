"""`pip install` of the package from the repository into a fresh venv (Debian's grpcio, protobuf
and numpy through --system-site-packages; no package index), then an import and one query from
outside the repository. The repository's clients/python and proto are copied first, so the
in-tree build leaves nothing in the checkout."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

from conftest import SOURCE_DIR


def test_pip_install_into_a_venv(tmp_path: Path, daemon) -> None:
    repo = tmp_path / "repo"
    shutil.copytree(SOURCE_DIR / "clients" / "python", repo / "clients" / "python",
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    shutil.copytree(SOURCE_DIR / "proto", repo / "proto")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)],
                   check=True, capture_output=True, timeout=120)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    p = subprocess.run([str(venv / "bin" / "pip"), "install", "--no-build-isolation",
                        "--no-deps", "--no-index", "--disable-pip-version-check", "-q",
                        str(repo / "clients" / "python")],
                       capture_output=True, text=True, timeout=240, env=env)
    assert p.returncode == 0, p.stdout + p.stderr
    script = """
import sys
import proxima
assert proxima.__file__.startswith(sys.prefix), proxima.__file__
with proxima.Client(sys.argv[1]) as c:
    s = c.create_scene([proxima.box("a", (0, 0, 0), (1, 1, 1)),
                        proxima.box("b", (2, 0, 0), (3, 1, 1))])
    print(c.query(s.scene_id).distances.tolist())
    c.delete_scene(s.scene_id)
"""
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    p = subprocess.run([str(venv / "bin" / "python"), "-c", script, daemon.address],
                       capture_output=True, text=True, timeout=60, env=env, cwd=outside)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[1.0, 1.0]"
    # The stubs were generated into the installed package, with their type stubs.
    site = next(venv.glob("lib/python3*/site-packages/proxima"))
    assert (site / "_pb" / "proxima_pb2.pyi").exists() and (site / "py.typed").exists()
