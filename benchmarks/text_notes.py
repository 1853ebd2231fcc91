"""A reproducible corpus of robot-log style notes: what a memory's text sense fills with.

``notes(n, seed)`` draws ``n`` notes from the templates below with ``random.Random(seed)``
(Python's Mersenne Twister: the same notes on every machine and version). No recorded or
licensed text: every word is in this file. Used by ``benchmarks/text_prior.py`` (the shipped
text prior is the probe null against ``notes(SAMPLE, PRIOR_SEED)``) and
``benchmarks/text_precision.py`` (the unrelated notes of its memory, another seed).
"""

from __future__ import annotations

import random

#: the seed of the notes the shipped text prior is estimated on
PRIOR_SEED = 0

OBJECTS = (
    "mug", "cup", "bottle", "screwdriver", "sponge", "box", "ball", "pen", "phone", "keys",
    "apple", "can", "plate", "spoon", "book", "towel", "hammer", "wrench", "cable", "tray",
    "bag", "jar", "lid", "brush", "glove", "bowl", "knife", "fork", "remote", "charger",
    "notebook", "folder", "basket", "bucket", "cloth", "tape", "scissors", "stapler", "lamp",
    "banana", "orange", "carton of milk", "water bottle", "toolbox", "drill", "pliers",
)  # fmt: skip
ADJECTIVES = (
    "red", "blue", "green", "empty", "full", "heavy", "small", "large", "wet", "dirty",
    "clean", "old", "new", "broken", "plastic", "metal", "wooden", "glass", "yellow", "black",
)  # fmt: skip
VERBS = (
    "picked up", "put down", "moved", "dropped", "handed over", "wiped", "opened", "closed",
    "inspected", "stacked", "sorted", "cleaned", "found", "placed", "carried", "pushed",
    "pulled", "rotated", "lifted", "set aside", "returned", "fetched", "weighed", "scanned",
)  # fmt: skip
PLACES = (
    "on the table", "in the drawer", "on the shelf", "near the sink", "in the bin",
    "by the door", "on the counter", "in the box", "on the floor", "next to the window",
    "on the desk", "in the cupboard", "on the tray", "under the bench", "in the fridge",
    "on the conveyor", "at station 2", "at the charging dock", "beside the printer",
)  # fmt: skip
ROOMS = (
    "kitchen", "hallway", "lab", "office", "living room", "garage", "workshop", "storage room",
    "corridor", "bathroom", "loading bay", "meeting room",
)  # fmt: skip
PEOPLE = ("the operator", "Anna", "the technician", "a visitor", "the supervisor", "Tom")
SAYINGS = (
    "hello", "stop", "thanks", "go ahead", "wait a moment", "good job", "try again",
    "be careful", "that is enough", "come here", "not now", "well done",
)  # fmt: skip
STATUS = (
    "battery at {n} percent",
    "charging at the dock, {n} percent",
    "arm calibration finished",
    "gripper error, retrying",
    "software update installed",
    "motor temperature {n} degrees",
    "task {n} complete",
    "task {n} failed, will retry",
    "joint {m} torque limit reached",
    "camera exposure adjusted",
    "wifi signal weak in the {r}",
    "map of the {r} updated",
    "emergency stop released",
    "self test passed",
    "low battery warning",
    "paused for {n} minutes",
    "waited {n} seconds for the door",
    "shift started",
    "shift ended, {n} tasks done",
    "log rotated",
)
EVENTS = (
    "navigation to the {r} started",
    "reached the {r}",
    "obstacle detected in the {r}",
    "door to the {r} was closed",
    "lights in the {r} are off",
    "the {r} floor is wet",
    "{p} entered the {r}",
    "{p} left the {r}",
    "{p} said {s}",
    "{p} asked for the {o}",
    "{p} took the {o}",
    "cannot reach the {o} {l}",
    "the {o} slipped from the gripper",
    "grip force too high on the {o}",
    "lost sight of the {o}",
    "the {a} {o} is {l}",
    "counted {n} items {l}",
    "the {o} is missing from the {r}",
    "a loud noise in the {r}",
    "someone left the {o} {l}",
)


def note(rng: random.Random) -> str:
    """One note: a manipulation (half of them), a status line or an event."""
    fill = {
        "n": rng.randint(1, 99),
        "m": rng.randint(1, 7),
        "r": rng.choice(ROOMS),
        "p": rng.choice(PEOPLE),
        "s": f'"{rng.choice(SAYINGS)}"',
        "o": rng.choice(OBJECTS),
        "a": rng.choice(ADJECTIVES),
        "l": rng.choice(PLACES),
    }
    u = rng.random()
    if u < 0.5:
        adj = f"{rng.choice(ADJECTIVES)} " if rng.random() < 0.4 else ""
        return f"{rng.choice(VERBS)} the {adj}{fill['o']} {fill['l']}"
    if u < 0.7:
        return rng.choice(STATUS).format(**fill)
    return rng.choice(EVENTS).format(**fill)


def notes(n: int, seed: int = PRIOR_SEED) -> list[str]:
    """``n`` notes drawn with ``random.Random(seed)`` (repeats possible, as in a real log)."""
    rng = random.Random(seed)
    return [note(rng) for _ in range(n)]


#: a second family, nothing like a robot's log (calendar, weather, news, shopping lines): the
#: unrelated notes of the young-memory scenario (``tests/search/test_text_prior_real.py``), so
#: the prior is not checked against notes drawn like its own
TOPICS = (
    "the weather", "the train timetable", "the football match", "the stock market",
    "the school concert", "the election", "the recipe for soup", "the garden", "the holiday",
    "the dentist appointment", "the library fine", "the new bakery", "the bike repair",
    "the tax return", "the birthday party", "the museum visit",
)  # fmt: skip
COMMENTS = (
    "was moved to Thursday", "is sunny with a light wind", "was cancelled again",
    "ended in a draw", "costs twelve euros", "starts at half past seven", "needs more salt",
    "was better than last year", "is fully booked", "has a long queue", "was on the radio",
    "changed its opening hours", "got a good review", "is due next month",
)  # fmt: skip


def other_notes(n: int, seed: int = 1) -> list[str]:
    """``n`` lines of the second family, drawn with ``random.Random(seed)``."""
    rng = random.Random(seed)
    return [f"{rng.choice(TOPICS)} {rng.choice(COMMENTS)}" for _ in range(n)]
