"""Store layer: id validation, the filter builder, URIs, schema (real LanceDB in tmp_path)."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest

from tactus_memory.errors import InvalidIdError, InvalidInputError, SpaceMismatchError
from tactus_memory.names import validate_id
from tactus_memory.storage.codes import vector_array
from tactus_memory.storage.connect import normalise_uri
from tactus_memory.storage.store import Store
from tactus_memory.storage.tables import facet_fields, place_fields
from tactus_memory.where import Where, finite_float

HOSTILE = [
    "s1' OR 1=1 --",
    'x"; drop table items',
    "",
    " ",
    "s1 ",
    "ünïcødé",
    "a" * 10_000,
    "-leading-dash",
    "semi;colon",
    "new\nline",
    "tab\t",
    "nul\x00",
    "sess%",
    "a/b",
]


@pytest.mark.parametrize("bad", HOSTILE)
def test_validate_id_rejects_hostile(bad: str) -> None:
    with pytest.raises(InvalidIdError, match="invalid session id"):
        validate_id(bad, "session id")


@pytest.mark.parametrize("bad", [None, 3, b"s1", ["s1"]])
def test_validate_id_rejects_non_strings(bad: object) -> None:
    with pytest.raises(InvalidIdError):
        validate_id(bad)


@pytest.mark.parametrize("good", ["s1", "robot-7:2026.11.21_a", "A", "x" * 128])
def test_validate_id_accepts_plain(good: str) -> None:
    assert validate_id(good) == good


def test_long_id_error_message_is_truncated() -> None:
    with pytest.raises(InvalidIdError) as err:
        validate_id("a" * 10_000 + "'")
    assert len(str(err.value)) < 300


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1; drop", None, True, "nan"])
def test_finite_float_rejects(bad: object) -> None:
    with pytest.raises(InvalidInputError):
        finite_float(bad, "after")


def test_where_renders_validated_pieces() -> None:
    sql = Where().session("s1").senses(["text", "touch"]).overlaps(1.5, 2.0).sql()
    assert sql == (
        "(session = 's1') AND (sense IN ('text', 'touch')) AND (t_end >= 1.5) AND (t <= 2.0)"
    )
    assert Where().sql() is None
    assert Where().ids([]).sql() == "(false)"


@pytest.mark.parametrize("bad", HOSTILE)
def test_where_rejects_hostile_everywhere(bad: str) -> None:
    with pytest.raises(InvalidIdError):
        Where().session(bad)
    with pytest.raises(InvalidIdError):
        Where().ids(["ok", bad])
    with pytest.raises(InvalidIdError):
        Where().sense(bad)


def test_where_rejects_bad_numbers() -> None:
    with pytest.raises(InvalidInputError):
        Where().overlaps(after=math.nan)
    with pytest.raises(InvalidInputError):
        Where().overlaps(before="0 OR 1=1")
    with pytest.raises(InvalidInputError, match="later than"):
        Where().overlaps(after=5, before=1)
    with pytest.raises(InvalidInputError):
        Where().episode("1 OR 1=1")  # type: ignore[arg-type]


def test_uri_normalisation() -> None:
    assert normalise_uri("file:///tmp/x") == "/tmp/x"
    assert normalise_uri("./memory") == "./memory"
    for uri in ("s3://bucket/mem", "gs://bucket/mem", "az://container/mem"):
        assert normalise_uri(uri) == uri
    for bad in ("http://example.com/x", "ftp://x", "s3://", "", "   "):
        with pytest.raises(InvalidInputError):
            normalise_uri(bad)


def _rows(store: Store, items: list[tuple[str, str, str, float, float]]) -> pa.Table:
    """Rows as the store keeps them (its schema: each vector with its sense's code)."""
    n, dim, schema = len(items), store.dim(), store.schema
    width = schema.field("vector").type.list_size
    one = np.eye(1, dim, dtype=np.float32)
    vec = pa.concat_arrays([vector_array(one, i[2], width) for i in items])
    return pa.table(
        {
            "id": [i[0] for i in items],
            "session": [i[1] for i in items],
            "sense": [i[2] for i in items],
            "t": [i[3] for i in items],
            "t_end": [i[4] for i in items],
            "vector": vec,
            "meta": ["{}"] * n,
            "text": [None] * n,
            "raw": [None] * n,
            "source": [""] * n,
            "episode": [None] * n,
            "created": [0.0] * n,
            **{f.name: pa.nulls(n, f.type) for f in place_fields()},  # unplaced
            **{f.name: pa.nulls(n, f.type) for f in facet_fields()},  # no touch facets
        },
        schema=schema,
    )


def test_filters_execute_on_real_lancedb(tmp_path) -> None:
    """Rendered filters run in LanceDB; overlap semantics on [t, t_end]; extreme floats parse."""
    store = Store(f"file://{tmp_path}/db")
    store.bind_space("fake", 4)
    store.write(
        _rows(
            store,
            [
                ("a", "s1", "text", 0.0, 1.0),
                ("b", "s1", "touch", 2.0, 5.0),
                ("c", "s2", "text", 3.0, 3.0),
                ("d", "s2", "touch", 9.0, 9.0),
            ],
        ),
        upsert=False,
    )
    assert store.count(Where().session("s1").sql()) == 2
    assert store.count(Where().overlaps(after=4.0).sql()) == 2  # b (ends 5) and d
    assert store.count(Where().overlaps(after=1.0, before=2.5).sql()) == 2  # a (ends 1), b
    assert store.count(Where().overlaps(after=1e20).sql()) == 0
    assert store.count(Where().overlaps(before=-1e-300).sql()) == 0
    assert store.count(Where().overlaps(after=-0.0, before=1e300).sql()) == 4
    assert store.count(Where().senses(["touch"]).session("s2").sql()) == 1
    # the quote escaper is a second line of defence behind validation
    assert Where(["id = " + "'" + "o''q" + "'"]).sql() == "(id = 'o''q')"
    assert store.count("id = 'o''q'") == 0


def test_space_recorded_and_checked(tmp_path) -> None:
    store = Store(str(tmp_path / "db"))
    store.bind_space("space-a", 8)
    again = Store(str(tmp_path / "db"))
    again.bind_space("space-a", 8)  # same space: fine
    with pytest.raises(SpaceMismatchError, match="space-a.*space-b"):
        Store(str(tmp_path / "db")).bind_space("space-b", 8)
    with pytest.raises(SpaceMismatchError, match="dim 8.*dim 16"):
        Store(str(tmp_path / "db")).bind_space("space-a", 16)


def test_upsert_is_idempotent(tmp_path) -> None:
    store = Store(str(tmp_path / "db"))
    store.bind_space("fake", 4)
    store.write(_rows(store, [("a", "s1", "text", 0.0, 0.0)]), upsert=True)
    store.write(_rows(store, [("a", "s1", "text", 7.0, 7.0)]), upsert=True)
    tbl = store.scan(None, ["id", "t"])
    assert tbl.num_rows == 1
    assert tbl.column("t")[0].as_py() == 7.0
