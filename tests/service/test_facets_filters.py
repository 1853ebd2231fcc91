"""Touch facets stored, returned and filtered (issue 50): the real touch sense (a tiny
checkpoint with the glove's profile) writes its windows' facets into a real LanceDB store; the
same filters and order answer alike from Python and over HTTP."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from tactus_memory.adapters.touch import TactusEncoder
from tactus_memory.cli.app import app
from tactus_memory.errors import InvalidInputError
from tactus_memory.search.captions import (
    CAPTION_PREFIX,
    GRASP_CAPTIONS_PREFIX,
    CaptionKey,
    Captions,
)
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tactus_memory.storage.tables import FACET_COLUMNS
from tactus_memory.touch.facets import (
    CAPTION_RULE,
    caption,
    facet_columns,
    grasp_captions,
    window_facets,
)
from tactus_memory.touch.profile import STAG_GLOVE
from tactus_memory.touch.regions import STAG_REGIONS
from tactus_memory.where import Where
from tests.helpers.service import FRAMES, make_memory

REST = 512  # raw resting reading (stag-format.md)
#: the windows written: (grip they show, regions loaded, raw level, start time)
GRASPS = [
    ("pinch", ("thumb", "index"), 620, 10.0),
    ("pinch", ("thumb", "index"), 700, 30.0),
    ("power", ("palm", "index", "middle", "ring"), 640, 50.0),
    ("press", ("palm",), 600, 70.0),
    ("tripod", ("thumb", "index", "middle"), 660, 90.0),
]


def glove_window(regions: tuple[str, ...], level: int, seed: int) -> np.ndarray:
    """(FRAMES, 32, 32) raw: the glove at rest, 6 taxels of each region pressed to ``level``."""
    rng = np.random.default_rng(seed)
    w = np.full((FRAMES, 32, 32), REST, np.int16) + rng.integers(-2, 3, (FRAMES, 32, 32))
    for name in regions:
        rows, cols = np.nonzero(STAG_REGIONS.taxels(name))
        w[:, rows[:6], cols[:6]] = level
    return w.astype(np.int16)


def fill(path: Path, checkpoint: Path):
    memory = make_memory(path, touch=False)
    memory.add_sense(TactusEncoder(checkpoint))
    ids = []
    for i, (_, regions, level, t) in enumerate(GRASPS):
        win = glove_window(regions, level, i)
        ids.append(memory.add("day", "touch", win, t=t, t_end=t + 1.0))
    return memory, ids


@pytest.fixture(scope="module")
def stored(tmp_path_factory, checkpoint: Path):
    """The memory the read-only tests share (the old-store test makes its own)."""
    return fill(tmp_path_factory.mktemp("facets") / "mem", checkpoint)


def test_facets_are_stored_at_write_time_and_returned(stored) -> None:
    memory, ids = stored
    hits = memory.search("something", k=10, senses=["touch"], group="window")
    assert len(hits) == len(GRASPS)
    by_id = {h.id: h for h in hits}
    for i, (grip, regions, level, _) in enumerate(GRASPS):
        f = by_id[ids[i]].facets
        want = window_facets(STAG_GLOVE.calibrate(glove_window(regions, level, i)), STAG_GLOVE)
        assert f["force"] == pytest.approx(float(want.force[0]))
        assert f["area"] == pytest.approx(len(regions) * 6 / 548)
        assert f["grip"] == grip
        assert {r for r, s in f["regions"].items() if s > 0} == set(regions)
    grasps = memory.search("something", k=10, senses=["touch"])  # auto: touch as grasps
    assert {g.facets["grip"] for g in grasps} == {g for g, *_ in GRASPS}
    for g in grasps:
        assert g.facets["duration"] == pytest.approx(1.0)
        assert g.facets["onset"] == g.t and g.facets["release"] == g.t_end


def _python(memory, **kw) -> list[str]:
    return [h.id for h in memory.search("something", k=10, senses=["touch"], **kw)]


def _http(client: TestClient, **kw) -> list[str]:
    r = client.get("/search", params={"q": "something", "k": 10, "sense": "touch", **kw})
    assert r.status_code == 200, r.text
    return [h["id"] for h in r.json()["hits"]]


CASES = [
    ({"grip": "pinch"}, {0, 1}),
    ({"regions": "thumb,index"}, {0, 1, 4}),
    ({"regions": "palm"}, {2, 3}),
    ({"force_min": 58.0}, {2, 4}),  # forces: 52.6, 55.0, 64.2, 47.2, 60.5
    ({"area_min": 0.03}, {2, 4}),
    ({"grip": "tripod", "force_max": 1e9}, {4}),
]


def test_filters_and_sort_answer_alike_in_python_and_over_http(stored) -> None:
    memory, ids = stored
    with TestClient(create_app(Settings(), memory=memory)) as client:
        for kw, want in CASES:
            for group in ("window", "auto"):
                py, http = _python(memory, group=group, **kw), _http(client, group=group, **kw)
                assert sorted(py) == sorted(http), (kw, group)
                if want is not None:
                    assert set(py) == {ids[i] for i in want}, (kw, group)
        forces = {h.id: h.facets["force"] for h in memory.search("x", k=10, group="window")}
        firm = {i for i, f in forces.items() if f >= 54.0}
        assert 0 < len(firm) < len(ids)
        assert set(_python(memory, group="window", force_min=54.0)) == firm
        for sort in ("-force", "force", "t", "-t"):
            py = _python(memory, group="window", sort=sort)
            assert py == _http(client, group="window", sort=sort)
            key = (lambda i: forces[i]) if "force" in sort else ids.index
            assert py == sorted(ids, key=key, reverse=sort.startswith("-"))
        firmest = memory.search("x", k=1, group="window", sort="-force")[0]
        assert firmest.id == ids[2]  # the power grasp: four regions pressed
        for route in ("/count", "/moments", "/last", "/first"):
            r = client.get(route, params={"q": "something", "grip": "pinch"})
            assert r.status_code == 200, r.text
            body = r.json()
            moments = body.get("moments") or ([body["moment"]] if body.get("moment") else [])
            seen = {e["id"] for m in moments for e in m["hits"]}
            assert seen <= {ids[0], ids[1]}, route  # only the pinches are asked of
            assert client.get(route, params={"q": "x", "grip": "fist"}).status_code == 422
        timeline = client.get("/sessions/day/timeline")  # takes no facet filter, still serves
        assert timeline.status_code == 200 and len(timeline.json()["items"]) == len(ids)
        at = client.get("/at", params={"x": 0, "y": 0, "z": 0, "r": 1, "grip": "pinch"})
        assert at.status_code == 422 and "facets" in at.text
        bad = client.get("/search", params={"q": "x", "grip": "fist"})
        assert bad.status_code == 422
        bad = client.get("/search", params={"q": "x", "regions": "thumb;drop"})
        assert bad.status_code == 422 and "region" in bad.text


def test_facet_filters_refuse_bad_values_and_old_stores(checkpoint: Path, tmp_path: Path) -> None:
    memory, ids = fill(tmp_path / "mem", checkpoint)
    with pytest.raises(InvalidInputError, match="sort"):
        memory.search("x", sort="hardest")
    with pytest.raises(InvalidInputError, match="force_min"):
        memory.search("x", force_min=5.0, force_max=1.0)
    with pytest.raises(InvalidInputError, match="region"):
        memory.search("x", regions="a b")
    before = {h.id: h.facets for h in memory.search("x", k=10, group="window")}
    memory.store.items.drop_columns(list(FACET_COLUMNS))  # a store made before facets
    memory.store.reread_layout()
    with pytest.raises(InvalidInputError, match="maintain --facets"):
        memory.search("x", grip="pinch")
    assert all(h.facets is None for h in memory.search("x", k=10, group="window"))
    by_time = [h.id for h in memory.search("x", k=10, group="window", sort="t")]
    assert by_time == ids  # time order needs no facet column
    res = CliRunner().invoke(app, ["maintain", "--facets", "--data", str(tmp_path / "mem")])
    # the facets are in, but this store's space (a test stand-in) cannot embed its captions:
    # exit 2, one line saying so, and the JSON says what failed
    assert res.exit_code == 2, res.output
    said = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(said) == 1 and "captions not embedded" in said[0] and "fake-hash" in said[0]
    report = json.loads(res.stdout.strip().splitlines()[-1])
    assert report["added"] and report["touch_rows"] == len(ids)
    assert "fake-hash" in report["captions_error"]
    memory.store.reread_layout()
    after = {h.id: h.facets for h in memory.search("x", k=10, group="window")}
    for i, f in after.items():  # as at write time, but for the float16 of the stored window
        assert f["grip"] == before[i]["grip"]
        assert f["force"] == pytest.approx(before[i]["force"], rel=1e-3)
        assert f["area"] == before[i]["area"]
        assert f["regions"] == pytest.approx(before[i]["regions"], abs=1e-3)
    assert {h.id for h in memory.search("x", k=10, grip="pinch", group="window")} == set(ids[:2])
    again = CliRunner().invoke(app, ["maintain", "--facets", "--data", str(tmp_path / "mem")])
    assert again.exit_code == 2 and not json.loads(again.stdout.strip().splitlines()[-1])["added"]


def test_rerun_export_carries_facets_as_scalars(stored, tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from tactus_memory.recordings.rerun import export_rerun

    memory, ids = stored
    out = export_rerun(memory, "day", tmp_path / "day.rrd")
    assert out.entities["facets/touch/force"] == len(GRASPS)
    chunks = RrdReader(out.path).stream().to_chunks()
    got = [
        v
        for c in chunks
        if c.entity_path == "/facets/touch/force"
        for row in c.to_record_batch().to_pydict()["Scalars:scalars"]
        for v in row
    ]
    want = [memory.get_item(i).facets["force"] for i in ids]
    assert sorted(got) == pytest.approx(sorted(want))


def test_captions_are_stored_per_rule_and_rebuilt(stored) -> None:
    """Issue 50: each stored window's caption (a function of its peak band, grip and active
    regions) has one embedding in the store, of the current rule, added by the write;
    ``Captions.rebuild`` (``tactus maintain --facets``) adds what is missing and removes
    another rule's."""
    memory, _ = stored
    have = memory.store.meta_items(CAPTION_PREFIX)
    assert have and all(k.startswith(f"{CAPTION_PREFIX}{CAPTION_RULE}/") for k in have)
    windows = memory.search("x", k=10, senses=["touch"], group="window")
    keys = {CaptionKey.of(facet_columns(h.facets)) for h in windows}
    assert {k.digest() for k in keys} == {k.rsplit("/", 1)[1] for k in have}
    for h in windows:  # the key's caption is the window's own, word for word
        assert CaptionKey.of(facet_columns(h.facets)).caption() == caption(h.facets)
    # every grasp caption of the rule, embedded by the first touch write (no search embeds)
    grasps = json.loads(memory.store.get_meta(f"{GRASP_CAPTIONS_PREFIX}{CAPTION_RULE}") or "{}")
    assert sorted(grasps) == grasp_captions() and len(grasps) == 72
    memory.store.set_meta(f"{CAPTION_PREFIX}{CAPTION_RULE - 1}/old", "{}")  # an older rule's
    memory.store.set_meta(f"{GRASP_CAPTIONS_PREFIX}{CAPTION_RULE - 1}", "{}")
    memory.store.delete_meta(next(iter(have)))
    report = Captions(memory.store, memory.space).rebuild()
    assert report == {"captions": len(have), "added": 1, "removed": 2}
    assert set(memory.store.meta_items(CAPTION_PREFIX)) == set(have)
    assert list(memory.store.meta_items(GRASP_CAPTIONS_PREFIX)) == [
        f"{GRASP_CAPTIONS_PREFIX}{CAPTION_RULE}"
    ]


def test_a_captions_windows_come_in_its_order(stored, monkeypatch) -> None:
    """Issue 50: the windows a caption answers come in its firmness's order (firm: firmest
    first; light: lightest first), ahead of windows of equal score; a key reads its windows
    by grip, regions and the band's force bounds (its pressure band times the taxels)."""
    memory, ids = stored
    captions = memory.ranker.captions
    pinch = {h.id: h for h in memory.search("x", k=10, group="window", grip="pinch")}
    assert set(pinch) == set(ids[:2])
    regions = facet_columns(pinch[ids[0]].facets)["regions"]
    base = Where().session("day")
    for band, first in (("firm", ids[1]), ("light", ids[0])):  # ids[1]: raw 700, ids[0]: 620
        key = CaptionKey(band, "pinch", regions)  # no taxel count: grip and regions alone
        monkeypatch.setattr(captions, "scores", lambda q, key=key: {key: (3.0, 0.9)})
        found = captions.search(np.zeros(memory.space.dim, np.float32), 5, ["touch"], base)
        assert [row["id"] for _, _, row in found][0] == first
        assert len(found) == 2 and {s for s, _, _ in found} == {3.0}
    key = CaptionKey.of(facet_columns(pinch[ids[1]].facets))
    assert key.taxels == 548 and key.band == "firm"  # force / 548 >= FIRM_PRESSURE
    firm_only = key.where(base).senses(["touch"])
    assert {r["id"] for r in memory.store.scan(firm_only.sql(), ["id"]).to_pylist()} == {ids[1]}
