"""The program's functions as compiled C: fatrop's evaluations at a fifth of their interpreted time.

casadi evaluates the expanded program (``nlp.build_nlp``, SX) in its virtual machine: on the screened
96-interval program that was 40 % of fatrop's solve (its Hessian, Jacobian and rows, and the copies into
fatrop's stages). The same program's functions (``nlp_g``, ``nlp_jac_g``, ``nlp_hess_l``, ... as casadi
names those an NLP solver asks for) are written here from one stage's rows, their Jacobian in the
stage's variables and the Hessian of their weighted sum (``nlp.stage_rows``: the expressions of the
program itself), mapped over the stages and placed into the expanded program's own sparsity; casadi
generates C for them, gcc compiles it, and fatrop takes them from the library by name (``nlpsol`` on a
shared library). The code is the stage's (a few hundred operations, its derivatives) and a loop over the
stages: a second of gcc per shape, where generating the expanded program took minutes at 48 intervals.
The same iterates as the interpreted program to the last bit on arm6's paths (bench/RESULTS.md,
"Issue 39 item 2: generated code").

A library is kept on disk, per program shape, under the user's cache folder (``cache_folder``), named by
a digest of casadi's version, the shape and this code's sources: built once per machine (in a
service's warm-up, ``planner.jerk.warm_up``), loaded in a few ms after. Where the C compiler is missing
or fails, the interpreted program solves (one warning per process).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from pvtflow.planner.jerk import nlp
from pvtflow.planner.jerk.nlp import CONTROL, PER_STAGE, STATE, stage_function, stage_rows

log = logging.getLogger("pvtflow.planner")

_FLAGS = ("-O2", "-fPIC", "-shared")
_COMPILE_TIMEOUT_S = 120.0
# the sources whose expressions a library holds: a change in either is a new library
_SOURCES = (Path(nlp.__file__), Path(__file__))


def cache_folder() -> Path:
    """Where the libraries are kept: ``PVTFLOW_CACHE_DIR``, else the user's cache folder
    (``XDG_CACHE_HOME``, else ~/.cache) /pvtflow; never the repository (an install may be read-only)."""
    explicit = os.environ.get("PVTFLOW_CACHE_DIR")
    if explicit:
        return Path(explicit) / "jerk"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pvtflow" / "jerk"


def wanted() -> bool:
    """Whether the programs are compiled at all: ``PVTFLOW_JERK_COMPILE=off`` keeps every program interpreted
    (the same answers, 1.4x fatrop's time), e.g. a test suite on a fresh machine, where every program shape its
    services warm up would cost a second or two of gcc."""
    return os.environ.get("PVTFLOW_JERK_COMPILE", "on").strip().lower() not in ("off", "0", "false", "no")


def compiler() -> str:
    """The C compiler: ``CC`` as make has it, else gcc."""
    return os.environ.get("CC") or "gcc"


def library_path(n: int, dof: int, torque: bool) -> Path:
    """The library of this shape in ``cache_folder``, named by what its code depends on."""
    digest = hashlib.sha256()
    digest.update(f"{ca.__version__}|{n}|{dof}|{int(torque)}|{' '.join(_FLAGS)}|{compiler()}".encode())
    for source in _SOURCES:
        digest.update(source.read_bytes())
    return cache_folder() / f"jerk_{n}_{dof}_{int(torque)}_{digest.hexdigest()[:16]}.so"


def _stage_blocks(dof: int, torque: bool) -> tuple[ca.Function, ca.Function, ca.Function]:
    """One stage's rows, (rows, their Jacobian) in z = (x_k, u_k, x_k+1), and the Hessian of lam' rows
    in (x_k, u_k) (the rows are linear in x_k+1); inputs z, D, the numbers per stage, inv, scale (, lam)."""
    nx, nu = len(STATE), len(CONTROL)
    z = ca.SX.sym("z", 2 * nx + nu)
    D = ca.SX.sym("D")
    per_stage = [ca.SX.sym(name, dof) for name in PER_STAGE]
    inv = ca.SX.sym("inv", 3 * dof)
    scale = ca.SX.sym("scale", nx + nu)
    g = stage_rows(stage_function(dof, torque), z[:nx], z[nx : nx + nu], z[nx + nu :], D, per_stage, inv, scale)
    lam = ca.SX.sym("lam", g.shape[0])
    inputs = [z, D, *per_stage, inv, scale]
    return (
        ca.Function("jerk_stage_g", inputs, [g]),
        ca.Function("jerk_stage_jac", inputs, [g, ca.jacobian(g, z)]),
        ca.Function("jerk_stage_hess", [*inputs, lam], [ca.hessian(ca.dot(lam, g), z[: nx + nu])[0]]),
    )


def _nonzeros(whole: ca.Sparsity, block: ca.Sparsity, n: int, corner: Callable[[int], tuple[int, int]]) -> list[int]:
    """For each nonzero of ``whole`` (column by column) its place among the nonzeros of n ``block``s
    side by side (stage k's block at ``corner(k)`` in ``whole``); ValueError where one is in no block."""
    rows, cols = block.get_triplet()
    place: dict[tuple[int, int], int] = {}
    for k in range(n):
        r0, c0 = corner(k)
        for i, (r, c) in enumerate(zip(rows, cols, strict=True)):
            place.setdefault((r0 + r, c0 + c), k * block.nnz() + i)
    found = [place.get(rc, -1) for rc in zip(*whole.get_triplet(), strict=True)]
    if min(found, default=0) < 0:
        raise ValueError("the stage's blocks do not cover the program's sparsity")
    return found


def library_functions(n: int, dof: int, torque: bool, jacobian: ca.Sparsity, hessian: ca.Sparsity) -> list[ca.Function]:
    """The functions fatrop asks an NLP for, by casadi's names, of the program ``nlp.build_nlp(n, dof,
    torque)``: its Jacobian and Hessian in their sparsities there (``jacobian``, ``hessian``)."""
    nx, nu = len(STATE), len(CONTROL)
    width = nx + nu
    rows_g, rows_jac, rows_hess = _stage_blocks(dof, torque)
    m = rows_g.size1_out(0)  # rows per stage
    x = ca.MX.sym("x", n * width + nx)
    p = ca.MX.sym("p", n * (1 + (len(PER_STAGE) + 3) * dof) + width)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", n * m)
    # the parameters as ``nlp.build_nlp`` orders them: D, the numbers per stage and the limits (n, dof) by
    # columns, the scales; a stage's as a column
    at = n
    per_stage = []
    for _ in PER_STAGE:
        per_stage.append(ca.reshape(p[at : at + n * dof], n, dof).T)
        at += n * dof
    inv = ca.reshape(p[at : at + 3 * n * dof], n, 3 * dof).T
    scale = ca.repmat(p[at + 3 * n * dof :], 1, n)
    z = ca.reshape(x[np.add.outer(np.arange(n) * width, np.arange(width + nx)).ravel().tolist()], width + nx, n)
    inputs = [z, p[:n].T, *per_stage, inv, scale]
    g = ca.vec(rows_g.map(n, "serial")(*inputs))
    g_jac, blocks = rows_jac.map(n, "serial")(*inputs)
    hess = rows_hess.map(n, "serial")(*inputs, ca.reshape(lam_g, m, n))
    jac = ca.MX(jacobian, blocks.nz[_nonzeros(jacobian, rows_jac.sparsity_out(1), n, lambda k: (k * m, k * width))])
    hess = ca.MX(hessian, hess.nz[_nonzeros(hessian, rows_hess.sparsity_out(0), n, lambda k: (k * width, k * width))])
    f = ca.sum1(x[[k * width + nx for k in range(n)]])  # the duration: the sum of the intervals' times
    grad_f = ca.densify(ca.jacobian(f, x).T)  # dense, as the expanded program's (fatrop's interface copies it whole)
    grad_gamma = lam_f * grad_f + ca.mtimes(jac.T, lam_g)
    both, lagrange, multipliers = ["x", "p"], ["x", "p", "lam_f", "lam_g"], [x, p, lam_f, lam_g]
    return [
        ca.Function("nlp_f", [x, p], [f], both, ["f"]),
        ca.Function("nlp_g", [x, p], [g], both, ["g"]),
        ca.Function("nlp_grad_f", [x, p], [grad_f], both, ["grad_f_x"]),
        ca.Function("nlp_jac_g", [x, p], [ca.vec(g_jac), jac], both, ["g", "jac_g_x"]),
        ca.Function("nlp_hess_l", multipliers, [grad_gamma, hess], lagrange, ["grad_gamma_x", "hess_gamma_x_x"]),
        ca.Function(
            "nlp_grad",
            multipliers,
            [f, g, grad_gamma, ca.gradient(lam_f * f + ca.dot(lam_g, g), p)],
            lagrange,
            ["f", "g", "grad_gamma_x", "grad_gamma_p"],
        ),
        ca.Function("nlp", [x, p], [f, g], both, ["f", "g"]),
    ]


def compile_library(functions: Sequence[ca.Function], target: Path) -> None:
    """``functions`` as C, compiled into ``target`` (written whole or not at all: processes may share
    the folder). OSError or subprocess.SubprocessError where the compiler fails."""
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as work:
        source = Path(work) / (target.stem + ".c")
        generator = ca.CodeGenerator(source.name, {"with_header": False})
        for function in functions:
            generator.add(function)
        generator.generate(work + os.sep)
        built = Path(work) / target.name
        subprocess.run(
            [compiler(), *_FLAGS, str(source), "-o", str(built), "-lm"],
            check=True,
            capture_output=True,
            timeout=_COMPILE_TIMEOUT_S,
        )
        os.replace(built, target)


_warned = threading.Event()  # one warning per process where the compiler is missing or fails


def compiled_fatrop(
    name: str,
    n: int,
    dof: int,
    torque: bool,
    interpreted: ca.Function,
    options: dict[str, object],
    build: bool = True,
) -> ca.Function | None:
    """fatrop on the compiled library of this shape (``interpreted``: fatrop on the expanded program, for its
    sparsities), compiled first where it is not on disk and ``build``; None where it cannot be had (a
    warning the first time the compiler fails: the interpreted program then solves)."""
    if not wanted():
        return None
    try:
        target = library_path(n, dof, torque)
        if not target.exists():
            if not build:
                return None
            if shutil.which(compiler()) is None:
                raise FileNotFoundError(f"no C compiler {compiler()!r}")
            jacobian = interpreted.get_function("nlp_jac_g").sparsity_out(1)
            hessian = interpreted.get_function("nlp_hess_l").sparsity_out(1)
            compile_library(library_functions(n, dof, torque, jacobian, hessian), target)
            # a library of an older code is never loaded again
            for stale in target.parent.glob(f"jerk_{n}_{dof}_{int(torque)}_*.so"):
                if stale != target:
                    stale.unlink(missing_ok=True)
        return ca.nlpsol(name, "fatrop", str(target), options)
    except (OSError, RuntimeError, ValueError, subprocess.SubprocessError) as exc:
        if not _warned.is_set():
            _warned.set()
            failed = isinstance(exc, subprocess.CalledProcessError)
            detail = exc.stderr.decode(errors="replace")[-500:] if failed else exc
            log.warning("the jerk-limited program is not compiled (%s): its solves take about 1.4x the time", detail)
        return None
