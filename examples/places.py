"""Places: a trajectory, items placed on it, and questions about where.

    python examples/places.py        # from the checkout, beside `make run` (same ./memory)

Session "walk": the robot drives along x at 0.5 m/s for 60 s (poses at 20 Hz in the `map`
frame); a note at 12 s and a glove grasp at 13 s are placed on the trajectory (x = 6 m), a
note with an explicit position stays where it was put.
"""

import numpy as np

from tactus_memory import Memory, TactusEncoder

memory = Memory.open()  # ./memory, the store `make run` serves
memory.add_sense(TactusEncoder())

t = np.arange(0.0, 60.0, 0.05)  # (N,) s, session clock, strictly increasing
position = np.column_stack([0.5 * t, np.zeros_like(t), np.zeros_like(t)])  # (N, 3) metres
orientation = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))  # (N, 4) x, y, z, w
memory.add_poses("walk", t, position, orientation, frame="map", source="odom")

window = np.full((8, 32, 32), 512, np.int16)  # raw glove frames, the hand at rest...
window[:, 10:22, 8:20] = 640  # ...and a palm pressing
memory.add("walk", "text", "picked up the drill", t=12.0)  # placed at the pose of t = 12 s
memory.add("walk", "touch", window, t=13.0, t_end=13.3)
memory.add("walk", "text", "note at the door", t=40.0, position=(3.0, 4.0, 0.0), frame="map")

for place in memory.where("where did I pick up the drill?", session="walk"):  # best first
    print("where:", place.position, place.frame, round(place.score, 2))
for item in memory.at((6.0, 0.0, 0.0), 1.5, session="walk", after=0, before=30):
    print("at x=6:", item.sense, item.t)  # items there, in time order
near = ((6.0, 0.0, 0.0), 2.0)  # a sphere: centre (x, y, z) and radius, metres
hits = memory.search("picked up the drill", near=near, frame="map")  # hits in the sphere
print("near:", [(h.sense, h.t, h.position) for h in hits])
print("count:", memory.count("picked up the drill", near=near))  # every question takes near=
print("timeline:", len(memory.timeline("walk", near=near)))
print("trajectory:", [(tr.frame, len(tr.t)) for tr in memory.trajectory("walk")])
