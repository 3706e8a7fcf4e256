"""Scratch: can fatrop take an MX program whose stages are one mapped stage function? Same answer? Faster?"""
import pickle, sys, time
import casadi as ca
import numpy as np
from pvtflow.planner.jerk import nlp as N
from pvtflow.planner.jerk.solve import _solver_options

def build_mx(n, dof, torque):
    stage = N.stage_function(dof, torque)
    m = len(N.FRACTIONS)
    nx, nu = len(N.STATE), len(N.CONTROL)
    D = ca.MX.sym("D", n)
    per_stage = [ca.MX.sym(name, n, dof) for name in ("q1", "q2", "q3", "e1", "e2", "ta", "tb")]
    inv = ca.MX.sym("inv", n, 3 * dof)
    scale = ca.MX.sym("scale", nx + nu)
    x_scale, u_scale = scale[:nx], scale[nx:]
    sigma_scale, sd_scale = u_scale[2], u_scale[2 + m]
    residual_scale = ca.vertcat(1.0, *([sigma_scale, sd_scale] * m))
    w = ca.MX.sym("w", (n + 1) * nx + n * nu)
    # stage layout: x0 u0 x1 u1 ... xn
    W = ca.reshape(w[: n * (nx + nu)], nx + nu, n)
    X = W[:nx, :]
    U = W[nx:, :]
    Xn = ca.horzcat(X[:, 1:], w[n * (nx + nu):])
    XS = X * ca.repmat(x_scale, 1, n)
    US = U * ca.repmat(u_scale, 1, n)
    args = [XS[0, :], XS[1, :], *(US[i, :] for i in range(nu)), D.T]
    args += [mat.T for mat in per_stage[:5]]
    args += [inv[:, :dof].T, inv[:, dof:2*dof].T, inv[:, 2*dof:].T, per_stage[5].T, per_stage[6].T]
    mapped = stage.map(n, "serial")
    x1, residual, rows = mapped(*args)
    G = ca.vertcat(Xn - x1 / ca.repmat(x_scale, 1, n), residual / ca.repmat(residual_scale, 1, n), rows)
    g = ca.vec(G)
    p = ca.vertcat(D, *(ca.vec(mat) for mat in per_stage), ca.vec(inv), scale)
    f = ca.sum2(U[0, :])
    return {"x": w, "p": p, "f": f, "g": g}

if __name__ == "__main__":
    cap = pickle.load(open(sys.argv[1], "rb"))
    shapes = sorted({(c["n"], c["dof"], c["torque"]) for c in cap})
    for shape in shapes:
        cases = [c for c in cap if (c["n"], c["dof"], c["torque"]) == shape]
        n, dof, torque = shape
        sx_nlp, eq = N.build_nlp(n, dof, torque)
        t0 = time.perf_counter(); mx_nlp = build_mx(n, dof, torque); t1 = time.perf_counter()
        opts = _solver_options("fatrop", eq)
        s_sx = ca.nlpsol("sx", "fatrop", sx_nlp, opts)
        t2 = time.perf_counter()
        s_mx = ca.nlpsol("mx", "fatrop", mx_nlp, opts)
        t3 = time.perf_counter()
        print(shape, "build mx", round(t1 - t0, 3), "nlpsol sx", round(t2 - t1, 3), "mx", round(t3 - t2, 3))
        # same g?
        a = cases[0]["args"]
        fs = ca.Function("fs", [sx_nlp["x"], sx_nlp["p"]], [sx_nlp["g"], sx_nlp["f"]])
        fm = ca.Function("fm", [mx_nlp["x"], mx_nlp["p"]], [mx_nlp["g"], mx_nlp["f"]])
        gs, gm = fs(a["x0"], a["p"]), fm(a["x0"], a["p"])
        print(" g diff", float(ca.mmax(ca.fabs(gs[0] - gm[0]))), float(gs[1] - gm[1]))
        for name, s in (("sx", s_sx), ("mx", s_mx)):
            s(**a)  # first solve
        for c in cases:
            out = {}
            for name, s in (("sx", s_sx), ("mx", s_mx)):
                t = time.perf_counter(); o = s(**c["args"]); dt = time.perf_counter() - t
                st = s.stats()
                out[name] = (dt * 1e3, st["iter_count"], float(o["f"]), st["success"])
            print(" ", {k: (round(v[0], 1), v[1], round(v[2], 6), v[3]) for k, v in out.items()})
