"""The README's Python API section runs: the first block is executed, the second (it needs a
sequence on disk) is compiled and every name it imports must exist with the attributes it uses."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _api_blocks() -> list[str]:
    text = README.read_text(encoding="utf-8")
    section = text.split("### Python API", 1)[1].split("\n### ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_readme_has_the_two_api_blocks() -> None:
    assert len(_api_blocks()) == 2


def test_solver_block_runs(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    namespace: dict[str, object] = {}
    exec(compile(_api_blocks()[0], "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    assert "CONVERGENCE" in out or "cm" in out
    t_rmse_m = namespace["t_rmse_m"]
    assert isinstance(t_rmse_m, float) and t_rmse_m < 0.05


def test_pipeline_block_names_exist() -> None:
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import RefineResult, SolveOutcome

    tree = ast.parse(_api_blocks()[1])
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = importlib.import_module(node.module or "")
            for alias in node.names:
                assert hasattr(module, alias.name), f"{node.module}.{alias.name}"
    # the attributes the block reads
    fields = set(RefineResult.__dataclass_fields__)
    assert {"metrics_after", "outcome"} <= fields
    assert "observability" in SolveOutcome.__dataclass_fields__
    RefineConfig(terms="G+F+W+Co", solver={"wall": {"sigma": 0.03}})


def test_your_own_data_commands_parse() -> None:
    """Every ``bimcap`` command of the README's "Your own data" section is one the command line
    accepts (same sub-commands, flags and choices)."""
    import shlex

    from bimcap.cli import build_parser

    text = README.read_text(encoding="utf-8")
    section = text.split("### Your own data", 1)[1].split("\n### ", 1)[0]
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", section, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            if line.startswith("bimcap "):
                commands.append(shlex.split(line, comments=True)[1:])
    assert {c[0] for c in commands} == {"import-conslam", "import-bag", "import-folder"}
    parser = build_parser()
    for args in commands:
        parsed = parser.parse_args(args)
        assert callable(parsed.func), args
