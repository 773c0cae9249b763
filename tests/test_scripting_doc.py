"""Every ``python`` block of docs/scripting.md runs, in order, on a small synthetic take."""

from __future__ import annotations

import re
from pathlib import Path

from tests.small_takes import render_take

DOC = Path(__file__).resolve().parents[1] / "docs" / "scripting.md"


def test_scripting_doc_blocks_run(tmp_path, capsys):
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(blocks) >= 8
    take = render_take(tmp_path / "take" / "Doc00", frames=6, seed=9, name="Doc00")
    out = tmp_path / "out"
    out.mkdir()
    ns = {"TAKE": take, "OUT": out}
    for i, code in enumerate(blocks):
        exec(compile(code, f"{DOC.name} block {i + 1}", "exec"), ns)
    text = capsys.readouterr().out
    assert "6 frames, 4 cameras" in text
    assert "refused:" in text
    assert "Clean Up Chin" in text
    assert "'done': 1" in text  # the batch summary
    assert text.rstrip().endswith("True")  # the replay is identical
    assert (out / "batch" / "Doc00.cara").is_file()
