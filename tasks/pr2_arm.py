"""The PR2-like 7-DoF right arm, from the primitive-shape URDF in assets/: its babblegen description, and its
ManiSkill agent (built when the simulator loads, so that this module imports without it)."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.robot import RobotSpec

from .registry import register_robot

URDF_PATH = Path(__file__).parent / "assets" / "pr2_like_arm.urdf"
BASE_LINK = "base_link"
TOOL_LINK = "r_gripper_link"
ARM_JOINTS = (
    "r_shoulder_pan_joint",
    "r_shoulder_lift_joint",
    "r_upper_arm_roll_joint",
    "r_elbow_flex_joint",
    "r_forearm_roll_joint",
    "r_wrist_flex_joint",
    "r_wrist_roll_joint",
)
ARM_LINKS = (
    "r_shoulder_pan_link",
    "r_shoulder_lift_link",
    "r_upper_arm_roll_link",
    "r_elbow_flex_link",
    "r_forearm_roll_link",
    "r_wrist_flex_link",
    "r_wrist_roll_link",
    "r_gripper_link",
)
# Raised and swung out to the robot's right, clear of the table and of most of the head camera's view.
HOME_QPOS = np.array([-1.6, -0.35, -1.6, -1.7, 0.0, -0.8, 0.0])


@cache
def register_agent() -> type:
    """Define the ManiSkill agent and register it (once)."""
    import sapien
    from mani_skill.agents.base_agent import BaseAgent, Keyframe
    from mani_skill.agents.controllers import PDJointPosControllerConfig
    from mani_skill.agents.registration import register_agent as maniskill_register_agent

    @maniskill_register_agent()
    class PR2LikeArm(BaseAgent):
        """Fixed torso, 7-DoF right arm, head camera mount; joint position control.

        Self-collisions are off in the simulator: the planner's collision model guards them, so simulation
        and planning agree on what may touch what. Gravity is off on the arm links, as on a robot whose
        controller compensates for it, so the PD controller tracks commanded joints closely.
        """

        uid = "pr2_like_arm"
        urdf_path = str(URDF_PATH)
        fix_root_link = True
        disable_self_collisions = True
        keyframes = dict(home=Keyframe(qpos=HOME_QPOS, pose=sapien.Pose()))
        arm_joint_names = list(ARM_JOINTS)
        stiffness = 2000.0
        damping = 200.0
        force_limit = 150.0

        @property
        def _controller_configs(self) -> dict[str, Any]:
            return dict(
                pd_joint_pos=dict(
                    arm=PDJointPosControllerConfig(
                        self.arm_joint_names,
                        lower=None,
                        upper=None,
                        stiffness=self.stiffness,
                        damping=self.damping,
                        force_limit=self.force_limit,
                        normalize_action=False,
                    )
                )
            )

        def _after_init(self) -> None:
            for link in self.robot.get_links():
                for obj in link._objs:
                    obj.disable_gravity = True
            self.tcp = next(link for link in self.robot.get_links() if link.name == TOOL_LINK)

    return PR2LikeArm


SPEC = register_robot(
    RobotSpec(
        uid="pr2_like_arm",
        urdf=URDF_PATH,
        base_link=BASE_LINK,
        tool_link=TOOL_LINK,
        joints=ARM_JOINTS,
        home_qpos=tuple(HOME_QPOS.tolist()),
        register_agent=register_agent,
        body_exempt_links=("r_shoulder_pan_link", "r_shoulder_lift_link"),
        self_exempt_pairs=(("r_shoulder_pan_link", "r_upper_arm_roll_link"),),
    )
)
