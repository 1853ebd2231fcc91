"""``resolve_space``: precedence (argument, environment, store record, default) and the
one-line errors, without loading any model (the Qwen3-VL paths are in test_space_e2e.py)."""

from __future__ import annotations

import pytest

from tactus_memory.errors import SpaceConfigError
from tactus_memory.spaces.resolve import SpaceChoice, resolve_space

MINILM_RECORD = {"name": "minilm-l6", "dim": 384}
QWEN_RECORD = {"name": "qwen3-vl-embedding-2b@512", "dim": 512, "fingerprint": "ab12"}


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("TACTUS_SPACE", "TACTUS_SPACE_PATH", "TACTUS_SPACE_DIM"):
        monkeypatch.delenv(name, raising=False)


def test_default_and_recorded_minilm() -> None:
    assert resolve_space().name == "minilm-l6"
    assert resolve_space(SpaceChoice(), MINILM_RECORD).dim == 384


def test_naming_another_space_than_the_store_is_one_line() -> None:
    with pytest.raises(SpaceConfigError) as exc:
        resolve_space(SpaceChoice(name="qwen3vl"), MINILM_RECORD)
    msg = str(exc.value)
    assert "'minilm-l6' (dim 384)" in msg and "--space" in msg and "\n" not in msg


def test_missing_folder_names_the_option_and_the_recorded_space() -> None:
    with pytest.raises(SpaceConfigError) as exc:
        resolve_space(SpaceChoice(), QWEN_RECORD)
    msg = str(exc.value)
    assert "'qwen3-vl-embedding-2b@512' (dim 512)" in msg
    assert "--space-path" in msg and "TACTUS_SPACE_PATH" in msg and "\n" not in msg


def test_environment_fills_what_is_not_given(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setenv("TACTUS_SPACE", "qwen3vl")
    with pytest.raises(SpaceConfigError, match="space 'qwen3vl' needs"):
        resolve_space()
    assert resolve_space(SpaceChoice(name="minilm")).name == "minilm-l6"  # the option wins
    monkeypatch.setenv("TACTUS_SPACE_PATH", str(tmp_path / "absent"))
    with pytest.raises(SpaceConfigError, match="is not a folder"):
        resolve_space()
    monkeypatch.setenv("TACTUS_SPACE_DIM", "big")
    with pytest.raises(SpaceConfigError, match="TACTUS_SPACE_DIM='big'"):
        resolve_space()


def test_a_folder_without_config_is_one_line(tmp_path) -> None:
    with pytest.raises(SpaceConfigError, match="config.json") as exc:
        resolve_space(SpaceChoice(name="qwen3vl", path=str(tmp_path)))
    assert "\n" not in str(exc.value)
