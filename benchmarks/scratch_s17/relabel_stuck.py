"""Scratch (session 17), a probe, not a protocol: copy a ceiling training set (.npz of active.ladder) with the
transition where each stuck_in_plant trajectory stopped made a large deviation (its recorded next state's water
fractions set to 0, so the label is about 1 whatever the stop pose), to measure what the ceiling would be if
the MDE knew that a move stopped by the plant is a failure. 30-42 % of those moves otherwise have a label
below d_max (stuck_labels.py): the cup stops within 7 cm of where the model says the move ends.
python benchmarks/scratch_s17/relabel_stuck.py IN.npz OUT.npz"""
import sys
import numpy as np

d = dict(np.load(sys.argv[1]))
traj = d["trajectory"]
last = np.r_[traj[1:] != traj[:-1], True]
stuck = last & (d["category"][traj] == "stuck_in_plant")
s_next = d["s_next"].copy()
s_next[stuck, 3:5] = 0.0
d["s_next"] = s_next
np.savez(sys.argv[2], **d)
print(f"{sys.argv[2]}: {int(stuck.sum())} stuck transitions relabelled of {len(traj)}")
