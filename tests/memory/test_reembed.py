"""Re-embedding what is stored (issue 22), on the real path: real LanceDB, real MiniLM, a
real pair of tactus-tiny checkpoints (tests/helpers/touch_pair.py) and real windows cut from
synthetic STAG recordings. A store written with checkpoint A is re-embedded with B: every
vector equals B's embedding of the stored raw window, the sense's provenance is B's, a run
killed mid-way resumes, a concurrent reader sees all-A or all-B, never a mix; rows whose raw
window was not kept are reported by id."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.errors import IdleWindowError, SenseConflictError
from tactus_memory.hashing import file_sha256
from tactus_memory.memory.main import Memory
from tactus_memory.memory.reembed import STAGING_PREFIX
from tactus_memory.storage.codes import CODE_DIMS, CODE_WEIGHT, code
from tactus_memory.storage.store import Store
from tactus_memory.training.data import load_stag
from tactus_memory.training.stream_eval import build_stream
from tests.helpers.progress import assert_bar_finished
from tests.helpers.touch_pair import Pair, train_pair

N_PER_SESSION = 20


class Killed(RuntimeError):
    """Stands in for a kill in the middle of a re-embedding."""


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> Pair:
    return train_pair(tmp_path_factory.mktemp("pair"))


@pytest.fixture(scope="module")
def windows(pair) -> np.ndarray:
    """(W, 8, 32, 32) raw int16 windows of the synthetic recordings, as a stream cuts them."""
    data = load_stag(pair.stag[0])
    st = build_stream(data, list(range(len(data.recordings))))
    assert len(st) >= 2 * N_PER_SESSION
    return st.frames[: 2 * N_PER_SESSION]


def _store_with_a(path, pair: Pair, windows: np.ndarray, space) -> tuple[Memory, list[str]]:
    mem = Memory.open(str(path), space=space, background=False)
    mem.add_sense(TactusEncoder(pair.a))
    ids = []
    for s, chunk in enumerate((windows[:N_PER_SESSION], windows[N_PER_SESSION:])):
        t = [float(i) for i in range(len(chunk))]
        ids += mem.add_many(f"s{s}", "touch", list(chunk), t=t, t_end=[x + 1.0 for x in t])
    mem.add("s0", "text", "picked up the mug", t=3.0)
    return mem, ids


def _vectors(store: Store, ids: list[str]) -> np.ndarray:
    tbl = store.scan(f"sense = 'touch' AND id IN ({', '.join(repr(i) for i in ids)})",
                     ["id", "vector"])  # fmt: skip
    by = dict(zip(tbl.column("id").to_pylist(), tbl.column("vector").to_pylist(), strict=True))
    return np.array([by[i] for i in ids], dtype=np.float32)


def _b_of_stored(mem: Memory, enc_b: TactusEncoder, ids: list[str]) -> np.ndarray:
    """B's embeddings of the stored (calibrated, float16) raw windows."""
    return enc_b.embed([mem.get_item(i).raw for i in ids])


def test_reembed_keeps_a_window_stored_idle(tmp_path, pair, windows, minilm_space) -> None:
    """A window stored idle on purpose (``keep_idle``) is re-embedded like the others, not
    refused by the touch sense's idle rule (which refuses it as a new write)."""
    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    idle = np.zeros(windows[0].shape, dtype=np.float32)  # (8, 32, 32) calibrated: no contact
    with pytest.raises(IdleWindowError):
        mem.add("s0", "touch", idle, t=100.0)
    kept = mem.add("s0", "touch", idle, t=100.0, options={"keep_idle": True})
    enc_b = TactusEncoder(pair.b)
    report = mem.reembed("touch", enc_b, batch=8)
    assert report.rows == len(ids) + 1 and report.missing == 0
    assert np.allclose(_vectors(mem.store, [kept]), _b_of_stored(mem, enc_b, [kept]), atol=1e-4)


def test_reembed_swaps_every_vector_to_b(tmp_path, pair, windows, minilm_space) -> None:
    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    enc_a, enc_b = TactusEncoder(pair.a), TactusEncoder(pair.b)
    before = _vectors(mem.store, ids)
    assert np.allclose(before, enc_a.embed(list(windows)), atol=1e-5)
    text_before = mem.search("picked up the mug", senses=["text"], k=1)[0]
    report = mem.reembed("touch", enc_b, batch=8)
    assert report.rows == len(ids) and report.missing == 0 and report.batches == 5
    after = _vectors(mem.store, ids)
    want = _b_of_stored(mem, enc_b, ids)
    assert np.allclose(after, want, atol=1e-5)
    assert not np.allclose(after, before, atol=1e-2)  # A and B really differ
    # B of the stored window = B of the original window, up to the float16 storage
    assert (np.sum(after * enc_b.embed(list(windows)), axis=1) > 0.999).all()
    # as stored, each swapped vector still carries the touch sense's code after it
    raw = mem.store.items.to_lance().to_table(columns=["vector"], filter="sense = 'touch'")
    tails = np.stack(raw.column("vector").to_numpy(zero_copy_only=False))[:, -CODE_DIMS:]
    assert np.allclose(tails, CODE_WEIGHT * code("touch"), atol=1e-6)
    prov = {s.name: s.provenance for s in mem.sense_info()}["touch"]
    sha_b = file_sha256(pair.b)
    assert prov["checkpoint_sha256"] == sha_b == report.provenance["checkpoint_sha256"]
    assert mem.senses["touch"] is enc_b
    # text untouched; the staging table is gone; a reopened memory records B
    text_after = mem.search("picked up the mug", senses=["text"], k=1)[0]
    assert text_after.id == text_before.id
    assert text_after.cosine == pytest.approx(text_before.cosine)
    tables = mem.store.db.list_tables()
    assert STAGING_PREFIX + "touch" not in set(getattr(tables, "tables", tables))
    again = Memory.open(str(tmp_path / "m"), space=minilm_space, background=False)
    prov = {s.name: s.provenance for s in again.sense_info()}["touch"]
    assert prov["checkpoint_sha256"] == file_sha256(pair.b)


def test_a_killed_reembed_resumes_and_readers_never_see_a_mix(
    tmp_path, pair, windows, minilm_space
) -> None:
    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    enc_b = TactusEncoder(pair.b)
    a_vecs = _vectors(mem.store, ids)
    b_vecs = _b_of_stored(mem, enc_b, ids)

    def kill_after_two(n: int) -> None:
        if n == 2:
            raise Killed

    with pytest.raises(Killed):
        mem.reembed("touch", enc_b, batch=8, on_batch=kill_after_two)
    assert np.allclose(_vectors(mem.store, ids), a_vecs, atol=1e-6)  # nothing swapped yet

    # a reader on its own connection, always on the latest version, while the rerun runs
    reader = Store(str(tmp_path / "m"), read_consistency_interval=0)
    seen: list[str] = []
    errors: list[BaseException] = []
    done = threading.Event()

    def read() -> None:
        try:
            while not done.is_set():
                v = _vectors(reader, ids)
                if np.allclose(v, a_vecs, atol=1e-5):
                    seen.append("A")
                elif np.allclose(v, b_vecs, atol=1e-5):
                    seen.append("B")
                else:
                    seen.append("mix")
        except BaseException as exc:  # noqa: BLE001  (reported below)
            errors.append(exc)

    th = threading.Thread(target=read, daemon=True)
    th.start()
    try:
        report = mem.reembed("touch", enc_b, batch=8)
    finally:
        done.set()
        th.join(timeout=60)
    assert not errors, errors
    assert report.staged_before == 16 and report.batches == 3  # 40 rows: 16 staged, 24 left
    assert np.allclose(_vectors(mem.store, ids), b_vecs, atol=1e-5)
    assert seen and "mix" not in seen, seen
    final = _vectors(reader, ids)
    assert np.allclose(final, b_vecs, atol=1e-5)


def test_rows_without_a_raw_window_are_reported(tmp_path, pair, windows, minilm_space) -> None:
    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    lost = sorted(ids[:3])
    mem.store.items.update(where=f"id IN ({', '.join(repr(i) for i in lost)})",
                           values_sql={"raw": "NULL"})  # fmt: skip
    a_lost = _vectors(mem.store, lost)
    report = mem.reembed("touch", TactusEncoder(pair.b), batch=16)
    assert report.missing == 3 and report.missing_ids == lost
    assert report.rows == len(ids) - 3
    assert np.allclose(_vectors(mem.store, lost), a_lost)  # kept, and said so


def test_an_encoder_of_another_sense_or_space_is_refused(tmp_path, pair, windows, minilm_space):
    from dataclasses import replace

    from tactus_memory.touch.checkpoint import load_checkpoint, save_checkpoint

    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    with pytest.raises(SenseConflictError):
        mem.reembed("touch", TactusEncoder(pair.b, name="glove"))
    ck = load_checkpoint(pair.b)
    other = tmp_path / "other.safetensors"
    cal = ck.meta["calibration"]
    targets = replace(ck.targets, space_name="elsewhere")
    save_checkpoint(other, ck.model, targets, space_dim=384, calibration=cal)
    with pytest.raises(SenseConflictError, match="elsewhere"):
        mem.reembed("touch", TactusEncoder(other))
    assert np.allclose(_vectors(mem.store, ids), TactusEncoder(pair.a).embed(list(windows)),
                       atol=1e-5)  # fmt: skip


def test_tactus_reembed_command(tmp_path, pair, windows, minilm_space) -> None:
    from tactus_memory.cli import app

    mem, ids = _store_with_a(tmp_path / "m", pair, windows, minilm_space)
    args = ["reembed", "--data", str(tmp_path / "m"), "--sense", "touch"]
    r = CliRunner().invoke(app, [*args, "--checkpoint", str(pair.b), "--batch", "16"])
    assert r.exit_code == 0, (r.output, r.exception)
    report = json.loads(r.stdout)
    assert_bar_finished(r.stderr, "reembed touch")  # the rows staged, with the time left
    assert report["rows"] == len(ids) and report["missing"] == 0
    assert report["provenance"]["checkpoint_sha256"] == file_sha256(pair.b)
    reader = Store(str(tmp_path / "m"), read_consistency_interval=0)
    assert np.allclose(_vectors(reader, ids), _b_of_stored(mem, TactusEncoder(pair.b), ids),
                       atol=1e-5)  # fmt: skip
    r = CliRunner().invoke(app, [*args, "--checkpoint", str(tmp_path / "none.safetensors")])
    assert r.exit_code == 2
