"""Writes ``fpgalink.json`` beside it: a Foxglove layout for fpgalink's live view and its
recordings (the same topics): the robot in 3D (its URDF, odometry's path and the emulator's
truth), each wheel's speed against its reference, the PWM, supervision's log and health.
Built with foxglove-sdk's typed layouts, so a topic renamed in the code shows up here:
``tests/fpgalink/live/test_layout.py`` checks the file is what this writes.

    python examples/foxglove/layout.py       # then in Foxglove: Layouts → Import from file
"""

from __future__ import annotations

from pathlib import Path

import foxglove.layouts as fl

HERE = Path(__file__).resolve().parent


def _wheels(board: str) -> fl.PlotPanel:
    topic = f"/board/{board}/telemetry"
    return fl.PlotPanel(title=f"board {board}: wheel speed and reference, deg/s",
                        config=fl.PlotConfig(paths=[
                            fl.PlotSeries(value=f"{topic}.{ch}_{field}",
                                          label=f"{board}/{ch.upper()} {field}")
                            for ch in ("a", "b") for field in ("speed", "ref")]))


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(title="the robot (odom: where the command started)",
                               config=fl.ThreeDeeConfig(
        follow_tf="base_link", fixed_frame="odom",
        layers={"grid": fl.BaseRendererGridLayerSettings(),
                "urdf": fl.BaseRendererUrdfLayerSettings(source_type="topic",
                                                         topic="/robot_description")},
        topics={"/robot/path": fl.BaseRendererPosesTopicSettings(
                    type="line", gradient=("#1f77b4", "#1f77b4")),
                "/robot/truth_path": fl.BaseRendererPosesTopicSettings(
                    type="line", gradient=("#ff7f0e", "#ff7f0e")),
                "/robot/pose": fl.BaseRendererPoseTopicSettings(type="arrow"),
                "/robot/truth_pose": fl.BaseRendererPoseTopicSettings(type="arrow",
                                                                      color="#ff7f0e")}))
    pwm = fl.PlotPanel(title="PWM (±32760 = ±100 %)", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value=f"/board/{b}/telemetry.{ch}_pwm", label=f"{b}/{ch.upper()}")
        for b in "LR" for ch in "ab"]))
    log = fl.LogPanel(title="supervision", config=fl.LogConfig(
        topic_to_render="/robot/supervision"))
    health = fl.RawMessagesPanel(title="health", config=fl.RawMessagesConfig(
        topic_path="/robot/health"))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1, content=three_d),
        fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(content=_wheels("L")), fl.SplitItem(content=_wheels("R")),
            fl.SplitItem(content=pwm),
            fl.SplitItem(content=fl.SplitContainer(direction="row", items=[
                fl.SplitItem(content=log), fl.SplitItem(content=health)]))]))]))


def render() -> str:
    import json

    return json.dumps(json.loads(layout().to_json()), indent=2) + "\n"


if __name__ == "__main__":
    (HERE / "fpgalink.json").write_text(render(), encoding="utf-8")
    print(f"wrote {HERE / 'fpgalink.json'}")
