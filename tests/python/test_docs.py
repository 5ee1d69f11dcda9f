"""docs/api.md's Python section runs: its first ```python block is the worked example in
clients/python/examples (checked and run by tests/clients/test_server_cli.py); every other block
runs here against the fixture's daemon (with `address` set, and the store "row" served), and
where the page follows a block with "It prints:" and a ``` block, prints exactly that."""
import os
import re
import subprocess
import sys
from typing import List, Optional, Tuple

import pytest

from conftest import SOURCE_DIR


def python_blocks() -> List[Tuple[str, Optional[str]]]:
    doc = (SOURCE_DIR / "docs" / "api.md").read_text()
    section = doc[doc.index("## Python"):]
    section = section[:section.index("\n## ", 1)]
    found = re.findall(r"```python\n(.*?)```\n(?:\nIt prints:\n\n```\n(.*?)```\n)?", section, re.S)
    return [(code, printed or None) for code, printed in found]


def test_the_page_has_examples() -> None:
    blocks = python_blocks()
    assert len(blocks) >= 4
    example = (SOURCE_DIR / "clients" / "python" / "examples" / "example.py").read_text()
    assert blocks[0][0] in example


@pytest.mark.parametrize("index", range(1, len(python_blocks())))
def test_snippet(index: int, daemon) -> None:
    code, printed = python_blocks()[index]
    prelude = f"address = {daemon.address!r}\n"
    p = subprocess.run([sys.executable, "-c", prelude + code], capture_output=True, text=True,
                       timeout=120, env=dict(os.environ))
    assert p.returncode == 0, f"docs/api.md Python block {index}:\n{code}\n{p.stderr}"
    if printed is not None:
        assert p.stdout == printed, f"docs/api.md Python block {index} printed:\n{p.stdout}"
