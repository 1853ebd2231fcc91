from typing import Any

from tests.helpers.service import window


def fill(memory: Any) -> None:
    for t, note in NOTES:
        memory.add("kitchen", "text", note, t=t)
    memory.add("kitchen", "touch", window(seed=1), t=2.0, t_end=2.3)


NOTES = [
    (1.0, "picked up the red mug"),
    (10.0, "put the mug on the shelf"),
    (20.0, "wiped the table"),
]
