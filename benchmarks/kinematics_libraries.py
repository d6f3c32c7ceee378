"""Other kinematics libraries behind babblegen's `ArmKinematics` interface (benchmarks/bench_kinematics.py compares
them): SAPIEN's Pinocchio model, pytorch_kinematics, and a probe of mplib's entry points."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from babblegen.world.kinematics import ArmKinematics


# --- the libraries behind babblegen's kinematics interface -------------------------------------------------
class SapienPinocchio:
    """SAPIEN's Pinocchio model behind ArmKinematics' interface (link_frames, link_transforms, jacobian,
    inverse_position), one configuration per library call. Enough of ArmKinematics' attributes are copied
    from `ref` for SphereCollisionModel and ArmPlanner.solve_ik to use it."""

    name = "sapien-pinocchio"

    def __init__(self, ref: ArmKinematics, urdf: Path):
        import sapien

        self._scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])  # physics only: visuals are dropped below
        loader = self._scene.create_urdf_loader()
        loader.fix_root_link = True
        builder = loader.load_file_as_articulation_builder(str(urdf))
        for link in builder.link_builders:
            link.visual_records = []
        self.articulation = builder.build()
        names = [link.name for link in self.articulation.links]
        joints = [j.name for j in self.articulation.active_joints]
        if joints != ref.joint_names:
            raise RuntimeError(f"joint order differs: {joints} vs {ref.joint_names}")
        self.model = self.articulation.create_pinocchio_model()
        self.backend = type(self.model).__module__
        self.urdf, self.link_names, self.joint_names = ref.urdf, ref.link_names, ref.joint_names
        self.lower, self.upper, self.dof = ref.lower, ref.upper, ref.dof
        self.index = [names.index(n) for n in ref.link_names]
        self.tool = self.index[-1]
        self._ref = ref
        self.first_only = True  # IK: stop at the first seed that converges
        self.target_rotation: np.ndarray | None = None  # IK: wxyz quaternion; None: the seed's orientation

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(q)
        rots = np.empty((len(q), len(self.index), 3, 3))
        poss = np.empty((len(q), len(self.index), 3))
        for b, row in enumerate(q):
            self.model.compute_forward_kinematics(row)
            for k, idx in enumerate(self.index):
                m = self.model.get_link_pose(idx).to_transformation_matrix()
                rots[b, k], poss[b, k] = m[:3, :3], m[:3, 3]
        return rots, poss

    def link_transforms(self, q: np.ndarray) -> np.ndarray:
        rot, pos = self.link_frames(q)
        out = np.zeros((*rot.shape[:2], 4, 4))
        out[..., :3, :3], out[..., :3, 3], out[..., 3, 3] = rot, pos, 1.0
        return out

    def tool_position(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(q)
        out = np.empty((len(q), 3))
        for b, row in enumerate(q):
            self.model.compute_forward_kinematics(row)
            out[b] = self.model.get_link_pose(self.tool).p
        return out

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positional tool Jacobian in the world frame: the link-frame Jacobian's linear rows, rotated."""
        q = np.atleast_2d(q)
        jac, tool = np.empty((len(q), 3, self.dof)), np.empty((len(q), 3))
        for b, row in enumerate(q):
            self.model.compute_forward_kinematics(row)
            m = self.model.get_link_pose(self.tool).to_transformation_matrix()
            jac[b] = m[:3, :3] @ self.model.compute_single_link_local_jacobian(row, self.tool)[:3]
            tool[b] = m[:3, 3]
        return jac, tool

    def inverse_position(
        self, target: np.ndarray, seeds: np.ndarray, tol: float = 2e-3, max_iters: int = 1000, **_: object
    ) -> tuple[np.ndarray, np.ndarray]:
        """Same contract as ArmKinematics.inverse_position, with Pinocchio's CLIK, which solves full 6-D poses
        only: the target orientation is the tool's orientation at each seed (or `self.target_rotation`).
        Seeds run one after another; with `self.first_only` they stop at the first that converges (the
        hand-written solver stops once one seed has), otherwise all run (more candidates for the collision
        filter). Results are clipped to the joint limits (CLIK ignores them) and their error is measured
        with babblegen's FK."""
        import sapien

        q = np.clip(np.array(seeds, dtype=np.float64), self.lower, self.upper)
        err = np.full(len(q), np.inf)
        for i, seed in enumerate(q):
            self.model.compute_forward_kinematics(seed)
            rot = self.target_rotation
            if rot is None:
                rot = self.model.get_link_pose(self.tool).q
            pose = sapien.Pose(np.asarray(target, dtype=np.float32), rot)
            sol, _, _ = self.model.compute_inverse_kinematics(
                self.tool, pose, initial_qpos=seed, eps=tol, max_iterations=max_iters
            )
            q[i] = np.clip(sol, self.lower, self.upper)
            err[i] = np.linalg.norm(self._ref.tool_position(q[i])[0] - target)
            if self.first_only and err[i] < tol:
                break
        return q, err


class TorchKinematics:
    """pytorch_kinematics' batched FK and Jacobian behind ArmKinematics' interface (float64, CPU)."""

    name = "pytorch_kinematics"

    def __init__(self, ref: ArmKinematics, urdf: Path):
        import pytorch_kinematics as pk
        import torch

        torch.set_num_threads(1)
        self.torch = torch
        self.chain = pk.build_serial_chain_from_urdf(urdf.read_text(), ref.link_names[-1]).to(dtype=torch.float64)
        if self.chain.get_joint_parameter_names() != ref.joint_names:
            raise RuntimeError("joint order differs")
        self.urdf, self.link_names, self.joint_names = ref.urdf, ref.link_names, ref.joint_names
        self.lower, self.upper, self.dof = ref.lower, ref.upper, ref.dof

    def link_transforms(self, q: np.ndarray) -> np.ndarray:
        fk = self.chain.forward_kinematics(self.torch.from_numpy(np.atleast_2d(q)), end_only=False)
        return self.torch.stack([fk[n].get_matrix() for n in self.link_names], dim=1).numpy()

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tf = self.link_transforms(q)
        return tf[..., :3, :3], tf[..., :3, 3]

    def tool_position(self, q: np.ndarray) -> np.ndarray:
        fk = self.chain.forward_kinematics(self.torch.from_numpy(np.atleast_2d(q)), end_only=True)
        return fk.get_matrix()[:, :3, 3].numpy()

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = self.torch.from_numpy(np.atleast_2d(q))
        return self.chain.jacobian(th)[:, :3].numpy(), self.tool_position(q)


def probe_mplib(urdf: Path) -> list[tuple[str, str]]:
    """Whether mplib is installed and which of its kinematics entry points survive (each in a subprocess)."""
    try:
        from importlib.metadata import version

        ver = version("mplib")
    except Exception:
        return [("mplib", "not installed")]
    home = "[-1.6,-0.35,-1.6,-1.7,0.0,-0.8,0.0]"
    links = "['base_link','r_shoulder_pan_link','r_shoulder_lift_link','r_upper_arm_roll_link'," + (
        "'r_elbow_flex_link','r_forearm_roll_link','r_wrist_flex_link','r_wrist_roll_link','r_gripper_link']"
    )
    joints = "['r_shoulder_pan_joint','r_shoulder_lift_joint','r_upper_arm_roll_joint','r_elbow_flex_joint'," + (
        "'r_forearm_roll_joint','r_wrist_flex_joint','r_wrist_roll_joint']"
    )
    probes = {
        "pinocchio.PinocchioModel(urdf)": (
            "import numpy as np, mplib.pymp.kinematics.pinocchio as P\n"
            f"m = P.PinocchioModel({str(urdf)!r}, np.array([0., 0., -9.81]), False)\n"
            "m.compute_forward_kinematics(np.zeros(7)); print(m.get_link_pose(8))"
        ),
        "kdl.KDLModel(urdf).chain_IK_NR": (
            "import numpy as np, mplib.pymp.kinematics.kdl as K\n"
            f"m = K.KDLModel({str(urdf)!r}, {links}, {joints}, False)\n"
            f"print(m.chain_IK_NR(8, np.array({home}), np.array([0.6, -0.3, 0.9, 1, 0, 0, 0.])))"
        ),
    }
    out = [("mplib", f"{ver} installed")]
    for label, code in probes.items():
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        if r.returncode == 0:
            out.append((label, "works (not benchmarked: add it here)"))
        elif r.returncode < 0:
            out.append((label, f"crashes: signal {-r.returncode} ({'SIGSEGV' if r.returncode == -11 else '?'})"))
        else:
            out.append((label, f"fails: {(r.stderr.strip().splitlines() or ['?'])[-1][:80]}"))
    return out
