"""Scratch: the program's functions from one per-stage SX function (its rows, Jacobian and Hessian blocks),
mapped over the stages in MX and assembled into the SX program's own sparsity; generated as C, compiled
with gcc, and given to fatrop as a library (nlpsol from the .so: casadi takes nlp_jac_g, nlp_hess_l, ...
from it by name)."""
import os, pickle, subprocess, sys, time
import casadi as ca
import numpy as np
from pvtflow.planner.jerk import nlp as N
from pvtflow.planner.jerk.solve import _solver_options


def stage_blocks(dof, torque):
    """One stage k: z = (x_k, u_k, x_k+1) scaled, its numbers, the scales, its multipliers -> its rows,
    their Jacobian in z, the Hessian of lam' rows in (x_k, u_k), as build_nlp writes them."""
    nx, nu = len(N.STATE), len(N.CONTROL)
    m = len(N.FRACTIONS)
    stage = N.stage_function(dof, torque)
    z = ca.SX.sym("z", 2 * nx + nu)
    D = ca.SX.sym("D")
    per = [ca.SX.sym(nm, dof) for nm in ("q1", "q2", "q3", "e1", "e2", "ta", "tb")]
    inv = ca.SX.sym("inv", 3 * dof)
    scale = ca.SX.sym("scale", nx + nu)
    x_scale, u_scale = scale[:nx], scale[nx:]
    residual_scale = ca.vertcat(1.0, *([u_scale[2], u_scale[2 + m]] * m))
    xk, uk, xk1 = z[:nx], z[nx:nx + nu], z[nx + nu:]
    xs, us = xk * x_scale, uk * u_scale
    q1, q2, q3, e1, e2, ta, tb = per
    x1, residual, rows = stage(xs[0], xs[1], *(us[i] for i in range(nu)), D, q1, q2, q3, e1, e2,
                               inv[:dof], inv[dof:2 * dof], inv[2 * dof:], ta, tb)
    g = ca.vertcat(xk1 - x1 / x_scale, residual / residual_scale, rows)
    lam = ca.SX.sym("lam", g.shape[0])
    J = ca.jacobian(g, z)
    H = ca.hessian(ca.dot(lam, g), z[: nx + nu])[0]
    ins = [z, D, *per, inv, scale, lam]
    return (ca.Function("jerk_stage_g", ins[:-1], [g]), ca.Function("jerk_stage_jac", ins[:-1], [g, J]),
            ca.Function("jerk_stage_hess", ins, [H]))


def nz_index(global_sp, local_sp, n, row_off, col_off):
    """For each nonzero of global_sp (column-major), its position in the nonzeros of n local blocks
    horzcat'ed (block k at rows row_off(k), columns col_off(k))."""
    lr, lc = local_sp.get_triplet()
    where = {}
    nnz = local_sp.nnz()
    for k in range(n):
        for i, (r, c) in enumerate(zip(lr, lc)):
            where.setdefault((row_off(k) + r, col_off(k) + c), k * nnz + i)
    gr, gc = global_sp.get_triplet()
    idx = [where.get((r, c), -1) for r, c in zip(gr, gc)]
    missing = sum(i < 0 for i in idx)
    return idx, missing


def build_functions(n, dof, torque, ref):
    """ref: the SX nlpsol of the same shape (its functions' sparsities)."""
    nx, nu = len(N.STATE), len(N.CONTROL)
    fg, fj, fh = stage_blocks(dof, torque)
    nv = (n + 1) * nx + n * nu
    x = ca.MX.sym("x", nv)
    np_ = n * (1 + 7 * dof + 3 * dof) + nx + nu
    p = ca.MX.sym("p", np_)
    lam_f = ca.MX.sym("lam_f")
    ng_stage = fg.sparsity_out(0).size1()
    lam_g = ca.MX.sym("lam_g", n * ng_stage)
    # p layout: D (n), 7 per-stage matrices (n, dof) column-major, inv (n, 3 dof) column-major, scale
    D = p[:n].T
    o = n
    per = []
    for _ in range(7):
        per.append(ca.reshape(p[o:o + n * dof], n, dof).T)
        o += n * dof
    inv = ca.reshape(p[o:o + n * 3 * dof], n, 3 * dof).T
    o += n * 3 * dof
    scale = p[o:o + nx + nu]
    w = nx + nu
    Z = ca.vertcat(ca.reshape(x[: n * w], w, n), ca.reshape(x[nx + nu:], w, n + 1)[:nx, :]) if False else None
    # z_k = x[k w : k w + w + nx]
    idx = np.array([[k * w + i for i in range(w + nx)] for k in range(n)]).T  # (w + nx, n)
    Z = ca.reshape(x[idx.ravel(order="F").tolist()], w + nx, n)
    args = [Z, D, *per, inv, ca.repmat(scale, 1, n)]
    LAM = ca.reshape(lam_g, ng_stage, n)
    g = ca.vec(fg.map(n, "serial")(*args))
    gj, Jb = fj.map(n, "serial")(*args)
    gj = ca.vec(gj)
    Hb = fh.map(n, "serial")(*args, LAM)
    jac_sp = ref.get_function("nlp_jac_g").sparsity_out(1)
    hess_sp = ref.get_function("nlp_hess_l").sparsity_out(1)
    ji, jmiss = nz_index(jac_sp, fj.sparsity_out(1), n, lambda k: k * ng_stage, lambda k: k * w)
    hi, hmiss = nz_index(hess_sp, fh.sparsity_out(0), n, lambda k: k * w, lambda k: k * w)
    assert jmiss == 0 and hmiss == 0, (jmiss, hmiss)
    J = ca.MX(jac_sp, ca.vec(Jb)[ji] if False else Jb.nz[ji])
    H = ca.MX(hess_sp, Hb.nz[hi])
    f = ca.sum1(x[[k * w + nx for k in range(n)]])
    grad_f = ca.densify(ca.jacobian(f, x).T)  # constant; dense as the SX program's (fatrop's interface copies it whole)
    grad_gamma_x = lam_f * grad_f + ca.mtimes(J.T, lam_g)
    fns = [
        ca.Function("nlp", [x, p], [f, g], ["x", "p"], ["f", "g"]),
        ca.Function("nlp_f", [x, p], [f], ["x", "p"], ["f"]),
        ca.Function("nlp_g", [x, p], [g], ["x", "p"], ["g"]),
        ca.Function("nlp_grad_f", [x, p], [grad_f], ["x", "p"], ["grad_f_x"]),
        ca.Function("nlp_jac_g", [x, p], [gj, J], ["x", "p"], ["g", "jac_g_x"]),
        ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [grad_gamma_x, H], ["x", "p", "lam_f", "lam_g"], ["grad_gamma_x", "hess_gamma_x_x"]),
    ]
    gamma = lam_f * f + ca.dot(lam_g, g)
    fns.append(ca.Function("nlp_grad", [x, p, lam_f, lam_g], [f, g, grad_gamma_x, ca.gradient(gamma, p)],
                           ["x", "p", "lam_f", "lam_g"], ["f", "g", "grad_gamma_x", "grad_gamma_p"]))
    return fns


if __name__ == "__main__":
    cap = pickle.load(open(sys.argv[1], "rb"))
    n = int(sys.argv[2]); flags = sys.argv[3] if len(sys.argv) > 3 else "-O2"
    cases = [c for c in cap if c["n"] == n]
    dof, torque = cases[0]["dof"], cases[0]["torque"]
    sx_nlp, eq = N.build_nlp(n, dof, torque)
    opts = _solver_options("fatrop", eq)
    ref = ca.nlpsol("ref", "fatrop", sx_nlp, opts)
    t0 = time.perf_counter()
    fns = build_functions(n, dof, torque, ref)
    # check against the reference functions
    a = cases[0]["args"]; x0, p0 = a["x0"], a["p"]
    lam = np.random.default_rng(0).normal(size=fns[2].size1_out(0))
    for nm, ins in (("nlp_g", [x0, p0]), ("nlp_jac_g", [x0, p0]), ("nlp_hess_l", [x0, p0, 1.0, lam]), ("nlp_grad_f", [x0, p0]), ("nlp_f", [x0, p0]), ("nlp_grad", [x0, p0, 1.0, lam])):
        r = ref.get_function(nm)(*ins); mine = [f for f in fns if f.name() == nm][0](*ins)
        r = r if isinstance(r, (list, tuple)) else [r]; mine = mine if isinstance(mine, (list, tuple)) else [mine]
        print(nm, [float(ca.mmax(ca.fabs(ca.DM(u) - ca.DM(v)))) for u, v in zip(r, mine)], [ca.DM(u).sparsity() == ca.DM(v).sparsity() for u, v in zip(r, mine)])
    t1 = time.perf_counter()
    cg = ca.CodeGenerator(f"jerklib_{n}.c", {"with_header": False})
    for f in fns:
        cg.add(f)
    cg.generate("/tmp/x39gen/")
    t2 = time.perf_counter()
    src = f"/tmp/x39gen/jerklib_{n}.c"; so = f"/tmp/x39gen/jerklib_{n}{flags}.so"
    subprocess.run(["gcc", "-fPIC", "-shared", flags, src, "-o", so, "-lm"], check=True)
    t3 = time.perf_counter()
    lib = ca.nlpsol("lib", "fatrop", so, opts)
    t4 = time.perf_counter()
    print("build", round(t1 - t0, 2), "gen", round(t2 - t1, 2), "gcc", flags, round(t3 - t2, 2), "load", round(t4 - t3, 3), "bytes", os.path.getsize(src))
    for s in (ref, lib):
        s(**a)
    res = {"ref": [], "lib": []}
    for rep in range(2):
        for c in cases:
            for name, s in (("ref", ref), ("lib", lib)):
                t = time.perf_counter(); o = s(**c["args"]); dt = time.perf_counter() - t
                st = s.stats()
                evals = sum(v for k, v in st.items() if k.startswith("t_wall_nlp"))
                res[name].append((dt * 1e3, st["iter_count"], float(o["f"]), evals * 1e3, np.asarray(o["x"]).ravel()))
    for name, r in res.items():
        a_ = np.array([v[:4] for v in r])
        print(name, "ms p50", round(float(np.median(a_[:, 0])), 2), "iters", a_[:, 1].astype(int).tolist()[:10], "evals p50", round(float(np.median(a_[:, 3])), 2),
              "per it", round(float(np.median(a_[:, 0] / a_[:, 1])), 3))
    print("x max diff", max(float(np.max(np.abs(u[4] - v[4]))) for u, v in zip(res["ref"], res["lib"])),
          "f max rel", max(abs(u[2] / v[2] - 1) for u, v in zip(res["ref"], res["lib"])))
