"""Scratch: fatrop's own timing table (print_level 10) for the interpreted and the compiled 96-interval program, one path."""
import pickle, sys
from pvtflow.planner.jerk.solve import Program
from pvtflow.planner.jerk.nlp import build_nlp
import pvtflow.planner.jerk.solve as S
cap = pickle.load(open("/tmp/x39_cap.pkl", "rb")); c = [c for c in cap if c["n"] == 96][0]
orig = S._solver_options
def loud(name, eq):
    o = orig(name, eq)
    if name == "fatrop": o["fatrop"]["print_level"] = 10
    return o
S._solver_options = loud
for compiled in (False, True):
    p = Program(96, 4, False, *build_nlp(96, 4, False))
    if compiled: p.use_compiled()
    s = p.solver("fatrop"); s(**c["args"]); print("=== compiled" if compiled else "=== interpreted", flush=True); s(**c["args"])
