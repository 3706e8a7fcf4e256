"""Scratch: fatrop's time per evaluated function (casadi stats) for the SX program, the MX program, and their generated C."""
import os, pickle, subprocess, sys, time
import casadi as ca
import numpy as np
from pvtflow.planner.jerk import nlp as N
from pvtflow.planner.jerk.solve import _solver_options
sys.path.insert(0, "scratch")
from mx_probe import build_mx
cap = pickle.load(open(sys.argv[1], "rb"))
n = int(sys.argv[2]); variants = sys.argv[3].split(",")
cases = [c for c in cap if c["n"] == n]
dof, torque = cases[0]["dof"], cases[0]["torque"]
sx_nlp, eq = N.build_nlp(n, dof, torque)
opts = _solver_options("fatrop", eq)
solvers = {}
for v in variants:
    kind, _, flag = v.partition(":")
    nlp = build_mx(n, dof, torque) if kind == "mx" else sx_nlp
    s = ca.nlpsol("s" + str(len(solvers)), "fatrop", nlp, opts)
    if flag:
        stem = f"/tmp/x39gen/{kind}_{n}_{dof}_{int(torque)}{flag}"
        if not os.path.exists(stem + ".so"):
            s.generate_dependencies("tmpgen.c", {"with_header": False}); os.replace("tmpgen.c", stem + ".c")
            t = time.perf_counter()
            subprocess.run(["gcc", "-fPIC", "-shared", flag, stem + ".c", "-o", stem + ".so", "-lm"], check=True)
            print(v, "gcc", round(time.perf_counter() - t, 1), "s", os.path.getsize(stem + ".c"), "bytes")
        s = ca.nlpsol("c" + str(len(solvers)), "fatrop", stem + ".so", opts)
    solvers[v] = s
    s(**cases[0]["args"])
tot = {v: {} for v in variants}
for rep in range(2):
    for c in cases:
        for v, s in solvers.items():
            t = time.perf_counter(); s(**c["args"]); dt = time.perf_counter() - t
            st = s.stats()
            d = tot[v]
            d.setdefault("wall", []).append(dt * 1e3)
            d.setdefault("iter", []).append(st["iter_count"])
            for k, val in st.items():
                if k.startswith("t_wall_nlp"):
                    d.setdefault(k[7:], []).append(val * 1e3)
for v, d in tot.items():
    print(v, {k: round(float(np.median(x)), 2) for k, x in d.items()}, "per iter", round(float(np.median(np.array(d["wall"]) / np.array(d["iter"]))), 3))
