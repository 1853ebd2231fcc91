"""Scores comparable across senses: per-sense null calibration of cosine similarities.

Why: in a shared space every sense still lives in its own region (the *modality gap*): a
text query has raw cosines around, say, 0.1 with every touch vector and 0.3 with every note,
so ranking by raw cosine lets any weak note beat the best touch window.

Method (two steps, both per sense):

1. **Query transform.** The query vector goes through the sense's ``query_transform``
   (touch removes its text-target centroid there), so it is compared in that sense's frame.
2. **Null normalisation.** A fixed bank of :data:`PROBES` (64 generic queries, unrelated
   to any particular memory) is embedded once per space. For sense *s* we take up to
   :data:`SAMPLE` of its stored vectors, compute all probe-vs-item cosines (after step 1)
   and keep their mean ``mu_s`` and standard deviation ``sigma_s``: the distribution of
   cosines that "chance" produces for this sense. A hit's score is the z-score

       score = (cosine - mu_s) / sigma_s

   i.e. how many null standard deviations above chance the match is. Raw cosine is kept
   as ``hit.cosine``. The statistics are persisted in the store's ``senses`` table and
   recomputed lazily when the sense's row count has doubled since the last estimate, until
   an estimate was made on at least :data:`FINAL_ROWS` rows: from then on they are frozen,
   so a hit's score no longer moves when unrelated data arrives (``GET /senses`` shows the
   rows each sense was calibrated on, ``calib_n``, and whether that is final). Before that,
   a young sense's scores move by design: its null distribution is still being learnt.
   ``tactus reembed`` (a new encoder) starts the estimate again.

**A prior for a young sense.** Estimated on a few rows, ``mu_s`` and ``sigma_s`` move with
every doubling, so a young memory's scores moved with unrelated data (+43 % for one note after
150 unrelated notes in another session, issue 46). A sense therefore may have a *prior*
calibration where one is shipped, and the estimate used is the blend

    mu = w * mu_own + (1 - w) * mu_prior     (sigma likewise),  w = min(1, n / FINAL_ROWS)

so the store's own estimate takes over as it grows and is alone once final. The priors: a
touch sense's is shipped beside its checkpoint (``touch/checkpoints/calibration-priors.json``,
keyed by the checkpoint's sha256, measured by ``benchmarks/calibration_prior.py``); a text
sense's beside its space (``spaces/calibration-priors.json``, keyed by space name: the MiniLM
space's, measured by ``benchmarks/text_prior.py`` on a reproducible corpus of robot-log notes;
three notes' scores then move <= 3.2 % after 150 unrelated notes, against 89 % without). A
sense without one (another space, a sense of your own) uses its own estimate alone.

``search_vector`` / ``search_like`` use the same statistics: their scores rank hits of one
sense exactly like cosine, and are comparable across senses to the extent the query looks
like a text query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: generic queries: everyday, robot-ish, deliberately unspecific
PROBES: tuple[str, ...] = (
    "something happened",
    "an object",
    "a thing on the table",
    "the robot did something",
    "what was that",
    "a moment ago",
    "in the kitchen",
    "holding something",
    "touching a surface",
    "a soft thing",
    "a hard thing",
    "something heavy",
    "something light",
    "a person said something",
    "the operator gave an instruction",
    "moving the arm",
    "a sound",
    "a colour",
    "picking it up",
    "putting it down",
    "opening the door",
    "closing the drawer",
    "a cup",
    "a tool",
    "a piece of cloth",
    "a metal object",
    "a plastic bottle",
    "a wooden block",
    "food",
    "a box",
    "a ball",
    "paper",
    "a phone",
    "keys",
    "a pen",
    "shoes",
    "a bag",
    "a plant",
    "glass",
    "a sponge",
    "walking",
    "waiting",
    "nothing in particular",
    "the morning",
    "yesterday",
    "a problem",
    "an error",
    "success",
    "it slipped",
    "pressing hard",
    "a gentle grasp",
    "cold",
    "warm",
    "rough texture",
    "smooth texture",
    "a small item",
    "a large item",
    "left side",
    "right hand",
    "on the shelf",
    "under the chair",
    "near the window",
    "the task",
    "a note",
)

#: stored vectors sampled per sense for the null statistics
SAMPLE = 2048
#: an estimate made on at least this many rows is final (never re-estimated): with the
#: 64 probes that is >= 131k probe-item cosines, whose mean and std no longer move materially
FINAL_ROWS = SAMPLE
#: floor on sigma so a degenerate sense (all identical vectors) does not explode scores
MIN_SIGMA = 1e-3


@dataclass(frozen=True)
class Calibration:
    """Null statistics of one sense: score = (cosine - mu) / sigma."""

    mu: float = 0.0
    sigma: float = 1.0
    n: int = 0  # rows the sense had when estimated (0: never estimated)

    def score(self, cosine: np.ndarray | float) -> np.ndarray | float:
        return (cosine - self.mu) / self.sigma

    @property
    def final(self) -> bool:
        """Estimated on at least FINAL_ROWS rows: frozen from now on."""
        return self.n >= FINAL_ROWS

    def stale(self, rows: int) -> bool:
        """Re-estimate when never estimated, or the row count has at least doubled and the
        estimate is not final yet."""
        return rows > 0 and (self.n == 0 or (rows >= 2 * self.n and not self.final))


def blend(own: Calibration, prior: Calibration | None) -> Calibration:
    """The calibration a search uses: ``own`` blended with ``prior`` by ``own.n / FINAL_ROWS``
    (the module docstring); ``own`` itself when final or without a prior."""
    if prior is None or own.final:
        return own
    w = own.n / FINAL_ROWS
    return Calibration(
        mu=w * own.mu + (1.0 - w) * prior.mu,
        sigma=max(w * own.sigma + (1.0 - w) * prior.sigma, MIN_SIGMA),
        n=own.n,
    )


def estimate(probes: np.ndarray, items: np.ndarray, rows: int) -> Calibration:
    """probes: (P, D) transformed unit probe queries; items: (M, D) unit vectors of one sense.

    Returns the mean and std of the (P x M) cosine matrix.
    """
    if items.shape[0] == 0:
        return Calibration()
    cos = probes.astype(np.float64) @ items.astype(np.float64).T
    return Calibration(mu=float(cos.mean()), sigma=max(float(cos.std()), MIN_SIGMA), n=int(rows))
