"""Commands that need no model open the store without loading one: in a process where torch,
sentence-transformers, transformers and ONNX Runtime cannot be imported at all, ``tactus
sessions``, ``timeline``, ``keys`` and, from Python, ``at`` (by position) and the deletes
answer on the default store (MiniLM and the shipped touch encoder recorded in it); a question
that does need the text model fails there in one line, exit 2 (so the block is real)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

#: the model runtimes, made unimportable in the child
BLOCKER = """
import sys

class NoModels:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {"torch", "sentence_transformers", "transformers", "onnxruntime"}:
            raise ModuleNotFoundError(f"no model may load here: {name}")
        return None

sys.meta_path.insert(0, NoModels())
"""


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactus_memory.adapters.touch import TactusEncoder
    from tactus_memory.memory.main import Memory

    path = tmp_path_factory.mktemp("nomodel") / "memory"
    raw = np.full((8, 32, 32), 512, np.int16)
    raw[:, 10:22, 8:20] = 700
    with Memory.open(str(path)) as memory:
        memory.add_sense(TactusEncoder())
        memory.add("kitchen", "touch", raw, t=1.0, position=(1.0, 2.0, 0.0))
        memory.add("kitchen", "text", "picked up the red mug", t=2.0, position=(1.0, 2.0, 0.0))
        memory.add("yard", "text", "the gate is open", t=1.0)
    return path


def _blocked(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    site = tmp_path / "blocker"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(BLOCKER)
    env = {"PYTHONPATH": str(site), "TACTUS_CACHE": str(tmp_path / "cache"), "PATH": "/usr/bin"}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, env=env, timeout=600
    )


#: run in the child: the commands through the CLI's own runner, then the library calls
CHILD = """
import json, sys
from typer.testing import CliRunner
from tactus_memory.cli import app
from tactus_memory.memory.main import Memory

store, out = sys.argv[1], {}
for name, args in {
    "sessions": ["sessions", "--data", store, "--json"],
    "timeline": ["timeline", "kitchen", "--data", store, "--json"],
    "keys": ["keys", "list", "--data", store],
    "search": ["search", "mug", "--data", store],
}.items():
    r = CliRunner().invoke(app, args)
    out[name] = {"code": r.exit_code, "stdout": r.stdout, "stderr": r.stderr}
m = Memory.open(store)
near = m.at((1.0, 2.0, 0.0), 0.5, session="kitchen")
out["at"] = [i.sense for i in near]
out["deleted"] = [m.delete_session("yard"), m.delete([near[1].id])]
out["sessions_after"] = [s.id for s in m.sessions()]
out["loaded"] = [k for k in ("torch", "onnxruntime", "sentence_transformers") if k in sys.modules]
print(json.dumps(out))
"""


def test_questions_that_need_no_model_answer_with_no_model_loadable(
    store: Path, tmp_path: Path
) -> None:
    done = _blocked(tmp_path, "-c", CHILD, str(store))
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.splitlines()[-1])
    for name in ("sessions", "timeline", "keys"):
        assert out[name]["code"] == 0, out[name]
    assert {s["id"] for s in json.loads(out["sessions"]["stdout"])} == {"kitchen", "yard"}
    assert [i["sense"] for i in json.loads(out["timeline"]["stdout"])] == ["touch", "text"]
    assert out["at"] == ["touch", "text"] and out["deleted"] == [1, 1]
    assert out["sessions_after"] == ["kitchen"] and out["loaded"] == []
    # and the block is real: a search needs the text model, and fails in one line, exit 2
    search = out["search"]
    assert search["code"] == 2 and "no model may load here" in search["stderr"], search
    assert "Traceback" not in search["stderr"] + search["stdout"]


def test_an_error_line_is_printed_as_written(capsys: pytest.CaptureFixture[str]) -> None:
    """A failure's one line is text, not markup: brackets in it (an extra's name) stay."""
    import typer

    from tactus_memory.cli.space_opts import fail

    with pytest.raises(typer.Exit) as exited:
        fail("exporting needs torch: pip install 'tactus-memory[train]' [bold]x[/]")
    assert exited.value.exit_code == 2
    err = capsys.readouterr().err
    assert "pip install 'tactus-memory[train]' [bold]x[/]" in err and err.count("\n") == 1
