"""Asking "when": a short kitchen session, then the temporal questions about it.

    python examples/kitchen.py       # from the checkout, beside `make run` (same ./memory)

Session "kitchen": notes of picking up a mug three times and dropping a can, a glove
pressing while the mug is held; then last / first / count / before / after / timeline /
episodes / moments, and a clock offset for the glove.
"""

import numpy as np

from tactus_memory import Memory, TactusEncoder

memory = Memory.open()  # ./memory, the store `make run` serves
memory.add_sense(TactusEncoder())

window = np.full((8, 32, 32), 512, np.int16)  # raw glove frames, the hand at rest...
window[:, 10:22, 8:20] = 640  # ...and a palm pressing
for t in (5.0, 20.0, 40.0):
    memory.add("kitchen", "text", "picked up the mug", t=t)
    memory.add("kitchen", "touch", window, t=t + 0.5, t_end=t + 0.8, source="glove-l")
memory.add("kitchen", "text", "dropped the can", t=30.0)

print(memory.last("picked up the mug", session="kitchen"))  # Moment | None
print(memory.first("picked up the mug", senses=["text"]))  # Moment | None
print(memory.count("picked up the mug", session="kitchen"))  # 3 (occurrences() for the list)
print(memory.before("dropped the can", window=30))  # Context: anchor + items 30 s before
print(memory.after("dropped the can", window=30, senses=["touch"]))  # items 30 s after
print(len(memory.timeline("kitchen", senses=["touch"], after=0, before=60)))  # time order
print(memory.timeline("kitchen", episodes=True))  # episodes (computed, not stored)
print(memory.segment_episodes("kitchen"))  # store episode ids: an explicit write
print(memory.search("holding a mug", k=5, group="moment", gap=1.0))  # moments
memory.set_clock_offset("kitchen", "touch", 2.5, source="glove-l")  # t_aligned = t + 2.5
