"""Hand-written arm kinematics (babblegen/world/kinematics.py) against the kinematics libraries installed.

The arm is tasks/assets/pr2_like_arm.urdf (7 revolute joints, base_link -> r_gripper_link). Compared with
babblegen's numpy code (each behind its interface: benchmarks/kinematics_libraries.py):

* SAPIEN 3's Pinocchio model: the URDF loaded into a physics-only ``sapien.Scene`` (visuals dropped, so no
  renderer is needed), then ``articulation.create_pinocchio_model()``. Without the ``pinocchio`` Python package
  SAPIEN uses its built-in C++ Pinocchio (``sapien.pysapien_pinocchio``); the script says which it got.
  One configuration per call, so a batch is a Python loop.
* pytorch_kinematics (installed as a ManiSkill dependency): batched torch FK and Jacobian (no IK row: its IK
  solves full poses and is a different algorithm again). torch is limited to one thread, like numpy here.
* mplib (ManiSkill pins 0.1.1): each entry point is probed in a subprocess; on this machine its Pinocchio
  model and KDL IK crash the interpreter (SIGSEGV), so they are reported and skipped.

What is measured:

(a) accuracy: the largest position and orientation difference from babblegen's FK, over ``--configs`` random
    configurations within the joint limits, for every link of the chain (all the links whose spheres the
    collision model places, the tool included), and of the tool's positional Jacobian;
(b) speed: FK of one configuration (all links; tool only), FK of batches of the sizes the planner uses (one
    state per validity check, up to ~75 states per RRTConnect edge check, 1,000), the planner's whole
    ``SphereCollisionModel.in_collision`` with each FK plugged in, the tool Jacobian (one configuration; 8 at
    once, as IK uses it), and the World's IK (``ArmPlanner.solve_ik``: its seeds, stages and tolerance;
    collision filter unchanged) with each library's IK plugged in, plus raw single-seed IK on reachable targets;
(c) lines of code of the hand-written module.

Times are the best of 5 repeats (the machine is shared), in microseconds or milliseconds per call.
Run: ``.venv/bin/python benchmarks/bench_kinematics.py [--configs 1000] [--ik-targets 60] [--seed 0]``
(about a minute; it imports ManiSkill for the task's obstacles but starts no simulator).
"""

from __future__ import annotations

import argparse
import ast
import io
import subprocess
import sys
import time
import tokenize
from collections import Counter
from pathlib import Path

import numpy as np
from kinematics_libraries import SapienPinocchio, TorchKinematics, probe_mplib
from scipy.spatial.transform import Rotation
from timing import per_call

from babblegen.world.collision import SphereCollisionModel
from babblegen.world.kinematics import ArmKinematics, UrdfModel

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tasks" / "assets" / "pr2_like_arm.urdf"
KIN_SOURCE = REPO / "babblegen" / "world" / "kinematics.py"
BASE, TOOL = "base_link", "r_gripper_link"


# --- timing -------------------------------------------------------------------------------------------------
def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) of a^T b for rotation matrices (..., 3, 3); accurate for tiny angles too."""
    m = np.swapaxes(a, -1, -2) @ b
    skew = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), 0.5 * (np.trace(m, axis1=-2, axis2=-1) - 1.0))


# --- the World's IK set-up, without the simulator ----------------------------------------------------------
def planning(kin: ArmKinematics):  # -> babblegen.world.planning.ArmPlanner
    """The World's planner (IK seed bank, collision model of the task's obstacles and the robot's base) for the
    default task, with `kin` as its kinematics and the robot's home pose (no simulator)."""
    from babblegen.tasks import DEFAULT_TASK, get_robot, get_task
    from babblegen.world.planning import ArmPlanner
    from babblegen.world.settings import WorldSettings

    task = get_task(DEFAULT_TASK)
    robot = get_robot(task.robot_uid)
    return ArmPlanner(task, robot, np.asarray(robot.home_qpos, dtype=np.float64), WorldSettings(), kin=kin)


# --- lines of code -------------------------------------------------------------------------------------------
def code_lines(source: str) -> set[int]:
    """Line numbers holding code: not blank, not only a comment, not a docstring."""
    lines: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT):
            lines.update(range(tok.start[0], tok.end[0] + 1))
    for node in ast.walk(ast.parse(source)):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            const = body[0].value
            if isinstance(const, ast.Constant) and isinstance(const.value, str):
                lines -= set(range(body[0].lineno, body[0].end_lineno + 1))
    return lines


def loc_report(path: Path) -> list[tuple[str, int]]:
    source = path.read_text()
    code = code_lines(source)
    tree = ast.parse(source)
    groups = {"URDF parsing (+ collision shapes)": 0, "FK": 0, "Jacobian": 0, "position IK": 0, "other": 0}

    def group_of(name: str) -> str:
        if name in ("_vec", "rpy_matrix", "transform", "Shape", "Joint", "UrdfModel"):
            return "URDF parsing (+ collision shapes)"
        if name == "jacobian":
            return "Jacobian"
        if name == "inverse_position":
            return "position IK"
        if name in ("axis_rotations", "ArmKinematics", "__init__", "_step", "limits", "link_transforms"):
            return "FK"
        if name in ("link_frames", "tool_position"):
            return "FK"
        return "other"

    counted: set[int] = set()
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == "ArmKinematics":
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    span = code & set(range(item.lineno - len(item.decorator_list), item.end_lineno + 1))
                    groups[group_of(item.name)] += len(span)
                    counted |= span
            span = code & set(range(node.lineno, node.end_lineno + 1)) - counted
            groups["FK"] += len(span)
            counted |= span
        elif isinstance(node, ast.FunctionDef | ast.ClassDef):
            span = code & set(range(node.lineno - len(node.decorator_list), node.end_lineno + 1))
            groups[group_of(node.name)] += len(span)
            counted |= span
    groups["other"] += len(code - counted)  # imports, module docstring excluded
    total = len(source.splitlines())
    return [("total lines", total), ("code lines (no blanks/comments/docstrings)", len(code)), *groups.items()]


# --- report ---------------------------------------------------------------------------------------------------
def table(title: str, header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    fmt = "  ".join(f"{{:<{widths[0]}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    lines = [title, fmt.format(*header), "-" * (sum(widths) + 2 * (len(widths) - 1))]
    lines += [fmt.format(*map(str, r)) for r in rows]
    return "\n".join(lines)


def us(seconds: float) -> str:
    return f"{seconds * 1e6:,.1f} us" if seconds < 1e-3 else f"{seconds * 1e3:,.2f} ms"


def import_seconds(module: str, repeats: int = 3) -> float:
    """Wall time of `python -c "import module"` in a fresh interpreter, less that of an empty one (best of n)."""

    def run(code: str) -> float:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
        return time.perf_counter() - t0

    empty = min(run("pass") for _ in range(repeats))
    return min(run(f"import {module}") for _ in range(repeats)) - empty


def solve_ik_row(arm, label: str, ik: object, targets: np.ndarray, ref: ArmKinematics) -> list[str]:
    """ArmPlanner.solve_ik over the targets from home with `ik` as its IK (collision filter unchanged)."""
    arm.kin = ik
    reasons: Counter[str] = Counter()
    times, errs = [], []
    for target in targets:
        t0 = time.perf_counter()
        sol, reason = arm.solve_ik(target, arm.home)
        times.append(time.perf_counter() - t0)
        reasons[reason or "ok"] += 1
        if sol is not None:
            errs.append(np.linalg.norm(ref.tool_position(sol)[0] - target))
    arm.kin = ref
    return [
        label,
        f"{reasons['ok']}/{len(targets)}",
        ", ".join(f"{k} {v}" for k, v in sorted(reasons.items()) if k != "ok") or "-",
        us(float(np.mean(times))),
        us(float(np.max(times))),
        f"{max(errs):.4f}" if errs else "-",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=1000, help="random configurations for the accuracy check")
    ap.add_argument("--ik-targets", type=int, default=60, help="targets for ArmPlanner.solve_ik and for raw IK")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)

    t0 = time.perf_counter()
    ref = ArmKinematics(UrdfModel.load(URDF), BASE, TOOL)
    t_load_ref = time.perf_counter() - t0
    import pytorch_kinematics  # noqa: F401  (imported here so that the load times below exclude imports)
    import sapien  # noqa: F401

    t0 = time.perf_counter()
    sap = SapienPinocchio(ref, URDF)
    t_load_sap = time.perf_counter() - t0
    t0 = time.perf_counter()
    tor = TorchKinematics(ref, URDF)
    t_load_tor = time.perf_counter() - t0
    libs: list[SapienPinocchio | TorchKinematics] = [sap, tor]
    print(f"arm: {URDF.relative_to(REPO)}, {ref.dof} DoF, links {ref.link_names[1:]}")
    print(f"SAPIEN Pinocchio backend: {sap.backend}; torch threads: {tor.torch.get_num_threads()}")
    print(table("mplib", ["entry point", "status"], [list(r) for r in probe_mplib(URDF)]))
    print()

    # (a) accuracy ------------------------------------------------------------------------------------------
    q = rng.uniform(ref.lower, ref.upper, (args.configs, ref.dof))
    rot0, pos0 = ref.link_frames(q)
    jac0, _ = ref.jacobian(q)
    rows = []
    for lib in libs:
        rot, pos = lib.link_frames(q)
        dp = np.linalg.norm(pos - pos0, axis=-1)
        da = rotation_angle(rot0, rot)
        jac, _ = lib.jacobian(q)
        rows.append(
            [
                lib.name,
                f"{dp[:, -1].max():.2e}",
                f"{da[:, -1].max():.2e}",
                f"{dp.max():.2e}",
                f"{da.max():.2e}",
                ref.link_names[int(np.unravel_index(dp.argmax(), dp.shape)[1])],
                f"{np.abs(jac - jac0).max():.2e}",
            ]
        )
    print(
        table(
            f"(a) accuracy vs babblegen FK over {args.configs} random configurations within the limits "
            f"(same URDF link frames, no offset; positions in m, angles in rad)",
            ["library", "tool pos", "tool rot", "any link pos", "any link rot", "worst link", "tool J (3xn)"],
            rows,
        )
    )
    print()

    # (b) speed: FK, collision checks, Jacobian -----------------------------------------------------------------
    arm = planning(ref)
    extent = float(np.linalg.norm(ref.upper - ref.lower))
    edge_states = int(np.ceil(0.2 * extent / 0.03)) + 1  # RRTConnect's default range, 0.03 rad resolution
    pairs = arm.bank_q[rng.integers(0, len(arm.bank_q), (200, 2))]
    direct = np.ceil(np.abs(pairs[:, 1] - pairs[:, 0]).max(axis=1) / 0.03).astype(int) + 2
    print(
        f"planner batch sizes: 1 per state validity check; an RRTConnect edge (range 0.2 x extent "
        f"{extent:.2f} rad) <= {edge_states} states; a direct motion between seed-bank configurations: "
        f"median {int(np.median(direct))}, max {direct.max()} states; the seed bank: one batch of 3200"
    )
    batches = [1, 10, edge_states, 1000]
    qs = rng.uniform(ref.lower, ref.upper, (max(batches), ref.dof))
    q1 = qs[:1]
    kins: list[ArmKinematics | SapienPinocchio | TorchKinematics] = [ref, sap, tor]
    names = ["babblegen (numpy)", sap.name, tor.name]
    rows = [
        ["import (fresh process, s)"]
        + [f"{import_seconds(m):.2f}" for m in ("babblegen.world.kinematics", "sapien", "pytorch_kinematics")],
        ["load URDF, after import (s)", *(f"{t:.3f}" for t in (t_load_ref, t_load_sap, t_load_tor))],
        ["FK tool only, 1 config", *(us(per_call(lambda k=k: k.tool_position(q1))) for k in kins)],
    ]
    for b in batches:
        qb = qs[:b]
        rows.append(
            [f"FK all links, batch {b}", *(us(per_call(lambda k=k, qb=qb: k.link_transforms(qb))) for k in kins)]
        )
    models = [arm.collision] + [
        SphereCollisionModel(
            k,
            arm.collision.obstacles,
            margin=arm.settings.collision_margin,
            body_exempt_links=arm.robot.body_exempt_links,
            self_exempt_pairs=arm.robot.self_exempt_pairs,
        )
        for k in (sap, tor)
    ]
    verdicts = [m.in_collision(q) for m in models]
    differ = [int((v != verdicts[0]).sum()) for v in verdicts]
    for b in batches:
        qb = qs[:b]
        rows.append(
            [f"in_collision, batch {b}", *(us(per_call(lambda m=m, qb=qb: m.in_collision(qb))) for m in models)]
        )
    rows.append(["tool Jacobian, 1 config", *(us(per_call(lambda k=k: k.jacobian(q1))) for k in kins)])
    rows.append(["tool Jacobian, batch 8", *(us(per_call(lambda k=k: k.jacobian(qs[:8]))) for k in kins)])
    rows.append(["in_collision verdicts differing", *(f"{d}/{len(q)}" for d in differ)])
    print(
        table("(b) speed per call (best of 5; in_collision = sphere model with each FK plugged in)", ["", *names], rows)
    )
    print()

    # (b) speed: IK ------------------------------------------------------------------------------------------------
    tol = arm.settings.ik_tolerance
    targets = arm.task.workspace.to_world(rng.uniform(0.0, 1.0, (args.ik_targets, 3)))
    rows = [solve_ik_row(arm, "babblegen DLS (position only, seeds batched)", ref, targets, ref)]
    sap.first_only = True
    rows.append(solve_ik_row(arm, "sapien CLIK (6-D), stop at first solved seed", sap, targets, ref))
    sap.first_only = False
    rows.append(solve_ik_row(arm, "sapien CLIK (6-D), all seeds", sap, targets, ref))
    sap.first_only = True
    print(
        table(
            f"ArmPlanner.solve_ik on {args.ik_targets} targets uniform in the task's workspace box, from home "
            f"(tolerance {tol} m, solver tolerance {tol / 2} m, {arm.settings.ik_seeds} seeds per stage, "
            "same collision filter; CLIK's target orientation: the seed's)",
            ["IK", "solved", "failures", "mean", "max", "max err m"],
            rows,
        )
    )
    # the solvers alone: one seed (home); targets the arm reaches (the tool poses of random configurations)
    reach_q = rng.uniform(ref.lower, ref.upper, (args.ik_targets, ref.dof))
    reach_rot, reach_pos = ref.link_frames(reach_q)
    rows = []
    variants: list[tuple[str, ArmKinematics | SapienPinocchio, bool]] = [
        ("babblegen DLS, position", ref, False),
        ("sapien CLIK, position + home's orientation", sap, False),
        ("sapien CLIK, the exact reachable pose", sap, True),
    ]
    for label, ik, exact in variants:
        ok, times = 0, []
        for i, target in enumerate(reach_pos[:, -1]):
            if isinstance(ik, SapienPinocchio):
                ik.target_rotation = (
                    np.roll(Rotation.from_matrix(reach_rot[i, -1]).as_quat(), 1).astype(np.float32) if exact else None
                )
            t0 = time.perf_counter()
            _, err = ik.inverse_position(target, arm.home[None], tol=tol * 0.5)
            times.append(time.perf_counter() - t0)
            ok += bool(err[0] < tol)
        rows.append([label, f"{ok}/{len(reach_pos)}", us(float(np.mean(times)))])
    sap.target_rotation = None
    print(table("raw IK, one seed (home), reachable targets", ["IK", "solved", "mean"], rows))
    print()

    # (c) lines of code ----------------------------------------------------------------------------------------
    print(table(f"(c) {KIN_SOURCE.relative_to(REPO)}", ["part", "lines"], [list(r) for r in loc_report(KIN_SOURCE)]))


if __name__ == "__main__":
    main()
