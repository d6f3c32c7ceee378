"""The PR2-like 7-DoF right arm as a ManiSkill agent, from the primitive-shape URDF in assets/."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import sapien
from mani_skill.agents.base_agent import BaseAgent, Keyframe
from mani_skill.agents.controllers import PDJointPosControllerConfig
from mani_skill.agents.registration import register_agent

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


@register_agent()
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
    def _controller_configs(self):
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

    def _after_init(self):
        for link in self.robot.get_links():
            for obj in link._objs:
                obj.disable_gravity = True
        self.tcp = next(link for link in self.robot.get_links() if link.name == TOOL_LINK)
