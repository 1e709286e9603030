"""The robot's URDF: generated from the robot description, the shipped file is that output
for the seed's robot, its joints are the joint states' names with the description's wheel
positions (REP-103), its masses add up to the robot's; and the emulator's physics body,
generated from the same description, puts the wheels where the URDF does."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace

import pytest

from fpgalink.protocol.robot import WHEEL_NAMES, seed_robot
from fpgalink.protocol.urdf import FixedJoint, fixed_joints, robot_urdf, seed_urdf


def floats(text: str | None) -> list[float]:
    assert text is not None
    return [float(v) for v in text.split()]


def child(element: ET.Element, tag: str) -> ET.Element:
    found = element.find(tag)
    assert found is not None, tag
    return found


def test_the_shipped_urdf_is_the_generators_output_for_the_seed_robot() -> None:
    assert seed_urdf() == robot_urdf(seed_robot())


def test_joints_are_the_joint_states_wheels_where_the_description_puts_them() -> None:
    description = seed_robot()
    root = ET.fromstring(robot_urdf(description))
    joints = {j.get("name"): j for j in root.iter("joint")}
    assert {"FL", "BL", "FR", "BR"} <= set(joints)
    for wheel in description.wheels:
        joint = joints[wheel.name]
        assert joint.get("type") == "continuous"
        assert child(joint, "parent").get("link") == "base_link"
        assert floats(child(joint, "axis").get("xyz")) == [0, 1, 0]
        origin = floats(child(joint, "origin").get("xyz"))
        assert origin == pytest.approx([wheel.x, wheel.y, 0.0])
    assert [w.name for w in description.wheels] == list(WHEEL_NAMES)
    # REP-103: the left wheels at +y (the seed's URDF had them at −y)
    assert floats(child(joints["FL"], "origin").get("xyz"))[1] > 0
    masses = [floats(m.get("value"))[0] for m in root.iter("mass")]
    assert sum(masses) == pytest.approx(description.body.mass)


def test_the_urdf_follows_the_description() -> None:
    description = seed_robot()
    heavier = replace(description, body=replace(description.body, mass=80.0))
    root = ET.fromstring(robot_urdf(heavier))
    masses = [floats(m.get("value"))[0] for m in root.iter("mass")]
    assert sum(masses) == pytest.approx(80.0)


def test_the_physics_body_puts_the_wheels_where_the_urdf_does() -> None:
    mujoco = pytest.importorskip("mujoco")
    from fpgaemu.robot import EmulatedRobot

    robot = EmulatedRobot(body="mujoco")
    assert robot.physics is not None
    model = robot.physics.model
    urdf = mujoco.MjModel.from_xml_string(seed_urdf())
    for name in WHEEL_NAMES:
        assert model.body(f"{name}_link").pos == pytest.approx(urdf.body(f"{name}_link").pos)
        assert model.body_mass[model.body(f"{name}_link").id] == pytest.approx(
            urdf.body_mass[urdf.body(f"{name}_link").id])
    chassis = model.body_mass[model.body("base_link").id]
    wheels = sum(model.body_mass[model.body(f"{n}_link").id] for n in WHEEL_NAMES)
    rotors = sum(model.body_mass[model.body(f"{n}_rotor").id] for n in WHEEL_NAMES)
    assert chassis + wheels + rotors == pytest.approx(seed_robot().body.mass)
    assert rotors < 0.5  # the rotors' inertia is their joints' armature, not mass


def test_wheels_renamed_rename_their_joints_and_links_only() -> None:
    names = {"FL": "left_front", "BL": "left_back"}
    root = ET.fromstring(robot_urdf(seed_robot(), names))
    joints = {j.get("name"): j for j in root.iter("joint")}
    assert {"left_front", "left_back", "FR", "BR"} <= set(joints)
    assert not {"FL", "BL"} & set(joints)
    assert child(joints["left_front"], "child").get("link") == "left_front_link"
    assert robot_urdf(seed_robot(), {}) == seed_urdf()


def test_fixed_joints_are_read_from_any_urdf() -> None:
    # The shipped one: the seed's IMU and its backward-facing laser.
    assert fixed_joints(seed_urdf()) == [
        FixedJoint("imu", "base_link", "ImuALink", (0.125, -0.03, 0.11), (0.0, 0.0, 0.0)),
        FixedJoint("laser_joint", "base_link", "laser", (0.39, 0.02, 0.23),
                   (0.0, 0.0, 3.14159))]
    # No origin: at the parent's.
    assert fixed_joints('<robot name="r"><joint name="j" type="fixed"><parent link="a"/>'
                        '<child link="b"/></joint></robot>') == [
        FixedJoint("j", "a", "b", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))]


@pytest.mark.parametrize(("text", "says"), [
    ("not xml", "not XML"),
    ("<sdf/>", "not a URDF"),
    ('<robot><joint name="j" type="fixed"><parent link="a"/></joint></robot>',
     "without its parent and child"),
    ('<robot><joint name="j" type="fixed"><parent link="a"/><child link="b"/>'
     '<origin xyz="1 2"/></joint></robot>', "three finite numbers"),
])
def test_a_urdf_that_cannot_be_read_says_why(text: str, says: str) -> None:
    with pytest.raises(ValueError, match=says):
        fixed_joints(text)
