"""Generates the gRPC stubs into the built package (proxima/_pb) before it is copied into the
wheel: gen_stubs.py, the same generator CMake uses. Metadata lives in pyproject.toml."""
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gen_stubs import generate  # noqa: E402


class BuildPyWithStubs(build_py):
    """build_py, then the stubs generated from the repository's proto into the build folder."""

    def run(self) -> None:
        super().run()
        if not self.dry_run:
            generate(Path(self.build_lib) / "proxima" / "_pb")


setup(cmdclass={"build_py": BuildPyWithStubs})
