"""The README's Python snippet runs as printed."""

import contextlib
import io
import re

from conftest import REPO


def test_readme_python_snippet_runs():
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README.md has no Python snippet"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(blocks[0], "README.md", "exec"), {})
    assert "numpy arrays: column 'n_rl', sample 401: value NaN is not finite" in out.getvalue()
