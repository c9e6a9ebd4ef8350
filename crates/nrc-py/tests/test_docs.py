"""The examples of docs/python.md run as written (every `python` block, in order, in one
namespace, from the repository's root)."""

import os
import re

from conftest import ROOT


def test_python_md_examples(capsys):
    text = (ROOT / "docs" / "python.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 4
    namespace = {}
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        for i, block in enumerate(blocks):
            exec(compile(block, f"docs/python.md block {i + 1}", "exec"), namespace)
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert "held-out relative L2" in out and "MAPE against 256 spp" in out
    print(out)
