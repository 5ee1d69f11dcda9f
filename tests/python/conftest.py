"""Fixtures of the proxima package's tests: one proximad on a free loopback port (GPU backend
where EGL starts, llvmpipe included, else the CPU one) serving a small massive-model store
("row", written by `proxima import`), and a Client of it.

Environment (set by CTest, tests/python/CMakeLists.txt): PROXIMAD and PROXIMA (the built daemon
and command-line tool), PYTHONPATH with the build tree's package, PROXIMA_SOURCE_DIR (the repo).
"""
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Iterator, List, Sequence, Tuple

import pytest

SOURCE_DIR = Path(os.environ.get("PROXIMA_SOURCE_DIR", Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(SOURCE_DIR / "tests" / "support"))
from cli_helpers import Daemon, box_mesh, write_off  # noqa: E402

import proxima  # noqa: E402


def tool(name: str) -> str:
    path = os.environ.get(name.upper())
    if not path or not os.path.exists(path):
        pytest.exit(f"set {name.upper()} to the built {name} (CTest does)", returncode=2)
    return path


def floor_grid(n: int, x0: float, y0: float, z: float, size: float):
    v = [(x0 + size * i / n, y0 + size * j / n, z) for j in range(n + 1) for i in range(n + 1)]
    f: List[Tuple[int, int, int]] = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    return v, f


@pytest.fixture(scope="session")
def models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A models folder with one store, "row": six boxes in a row (pairs touching, 0.05 apart and
    overlapping) on a floor grid, split into pieces of 64 KiB (as tests/cli/test_massive_cli.py)."""
    tmp = tmp_path_factory.mktemp("models")
    meshes = tmp / "meshes"
    meshes.mkdir()
    shift = [0.0, -1.0, 0.0, -0.95, 0.0, -1.3]
    for i in range(6):
        x = 2.0 * i + shift[i]
        write_off(str(meshes / f"box-{i}.off"), [box_mesh((x, 0, 0), (x + 1, 1, 1))])
    write_off(str(meshes / "floor.off"), [floor_grid(40, -1, -1, 0.0, 14)])
    folder = tmp / "models"
    p = subprocess.run([tool("proxima"), "import", "--store", str(folder / "row"),
                        "--max-piece-bytes", "64K", "--quiet", str(meshes)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    return folder


@pytest.fixture(scope="session")
def daemon(models: Path) -> Iterator[Daemon]:
    d = Daemon(tool("proximad"), "--models", str(models), "--cache-bytes", str(256 * 1024),
               "--log-level", "warn")
    yield d
    status = d.stop()
    log = d.log()
    d.close()
    assert status == 0, f"proximad exited with {status} after SIGTERM; stderr:\n{log}"


@pytest.fixture
def client(daemon: Daemon) -> Iterator[proxima.Client]:
    with proxima.Client(daemon.address, timeout=60) as c:
        yield c


def local_verify(store: Path, tolerance: float) -> Sequence[dict]:
    """`proxima verify --store --brute-force`: the reference pairs."""
    p = subprocess.run([tool("proxima"), "verify", "--store", str(store), "--tolerance",
                        repr(tolerance), "--brute-force", "--quiet", "--json"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)["pairs"]
