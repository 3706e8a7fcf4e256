"""Scratch: the MX-mapped program's functions as generated C (generate_dependencies + gcc), fatrop from the .so."""
import os, pickle, subprocess, sys, time
import casadi as ca
import numpy as np
from pvtflow.planner.jerk import nlp as N
from pvtflow.planner.jerk.solve import _solver_options
sys.path.insert(0, "scratch")
from mx_probe import build_mx

flags = sys.argv[2] if len(sys.argv) > 2 else "-O2"
which = sys.argv[3] if len(sys.argv) > 3 else "mx"
cap = pickle.load(open(sys.argv[1], "rb"))
shapes = sorted({(c["n"], c["dof"], c["torque"]) for c in cap})
os.makedirs("/tmp/x39gen", exist_ok=True)
for shape in shapes:
    cases = [c for c in cap if (c["n"], c["dof"], c["torque"]) == shape]
    n, dof, torque = shape
    sx_nlp, eq = N.build_nlp(n, dof, torque)
    opts = _solver_options("fatrop", eq)
    s_sx = ca.nlpsol("sx", "fatrop", sx_nlp, opts)
    nlp = build_mx(n, dof, torque) if which == "mx" else sx_nlp
    s_mx = ca.nlpsol("mx", "fatrop", nlp, opts)
    stem = f"/tmp/x39gen/{which}_{n}_{dof}_{int(torque)}"
    t0 = time.perf_counter()
    s_mx.generate_dependencies(os.path.basename(stem) + ".c", {"with_header": False})
    os.replace(os.path.basename(stem) + ".c", stem + ".c")
    t1 = time.perf_counter()
    subprocess.run(["gcc", "-fPIC", "-shared", flags, stem + ".c", "-o", stem + ".so", "-lm"], check=True)
    t2 = time.perf_counter()
    s_c = ca.nlpsol("c", "fatrop", stem + ".so", opts)
    t3 = time.perf_counter()
    print(shape, "gen", round(t1 - t0, 2), "gcc", flags, round(t2 - t1, 2), "load", round(t3 - t2, 3), "bytes", os.path.getsize(stem + ".c"))
    for s in (s_sx, s_c):
        s(**cases[0]["args"])
    for c in cases:
        out = {}
        for name, s in (("sx", s_sx), ("c", s_c)):
            t = time.perf_counter(); o = s(**c["args"]); dt = time.perf_counter() - t
            st = s.stats()
            out[name] = (round(dt * 1e3, 1), st["iter_count"], float(o["f"]), st["success"], np.asarray(o["x"]).ravel())
        d = float(np.max(np.abs(out["sx"][4] - out["c"][4])))
        print(" ", {k: v[:4] for k, v in out.items()}, "xdiff", d)
