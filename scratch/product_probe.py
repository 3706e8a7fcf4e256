"""Scratch: the product's compiled program (Program.use_compiled) against the interpreted one on the captured args."""
import os, pickle, sys, time
import numpy as np
from pvtflow.planner.jerk.solve import Program, _solve_now
from pvtflow.planner.jerk.nlp import build_nlp
cap = pickle.load(open(sys.argv[1], "rb"))
for n in (48, 96):
    cases = [c for c in cap if c["n"] == n]
    dof, torque = cases[0]["dof"], cases[0]["torque"]
    a = Program(n, dof, torque, *build_nlp(n, dof, torque)); b = Program(n, dof, torque, *build_nlp(n, dof, torque))
    t = time.perf_counter(); ok = b.use_compiled(); print(n, "use_compiled", ok, round(time.perf_counter() - t, 2), "s")
    ta, tb, same = [], [], 0
    for rep in range(2):
        for c in cases:
            sa = _solve_now(a, c["args"], c["scale"], float("inf"))[0]; sb = _solve_now(b, c["args"], c["scale"], float("inf"))[0]
            same += np.array_equal(sa.h, sb.h) and np.array_equal(sa.sd, sb.sd)
    print(n, "fatrop p50 ms", round(np.median(a.fatrop_s) * 1e3, 1), "->", round(np.median(b.fatrop_s) * 1e3, 1), "identical", same, "of", 2 * len(cases), "solver", b.solvers["fatrop"].name())
