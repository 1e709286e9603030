"""``fpgalink-ros2 --lifecycle``: the node as a managed (lifecycle) node.

- unconfigured: the boards are not opened; no topics but the lifecycle services
- configure: the boards opened and started, every ROS parameter declared (board parameters
  read from the boards, ``-p`` overrides set on them), the parameter services up;
  failure (boards not reached, a bad ``-p``) leaves the node unconfigured as it was (what
  that configure declared and created withdrawn), the reason in the log: configure can be
  asked again
- activate: publishing (``robot_description`` and ``/tf_static`` then) and commands
- deactivate: publishing and commands stop, every board disabled
- cleanup: the boards closed, what configure declared and created withdrawn (its
  parameters, topics and services): unconfigured as at start, to be configured again
- shutdown (from any state): the boards closed, and the process ends (exit 0)

Transition callbacks run on rclpy's executor thread and wait for the asyncio loop, which
owns the boards, to carry them out (as parameter sets do).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
from collections.abc import Coroutine, Mapping
from typing import Any

from rclpy.exceptions import ParameterException, ParameterImmutableException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from fpgalink.errors import FpgalinkError
from fpgalink.protocol import IdentityMismatch
from fpgalink.protocol.robot import RobotDescription
from fpgalink.robot import Robot, RobotError
from fpgalink.ros2.bag import NodeBag
from fpgalink.ros2.node import NODE_NAME, BadOverride, RosBridge, spin_in_thread

__all__ = ["run_managed"]

#: How long a transition may take on the asyncio side (opening boards is the longest).
TRANSITION_TIMEOUT_S = 60.0


class _NodeMark:
    """What a node has before a configure, to give back what a failed configure added:
    its parameters (declared again next time, not ParameterAlreadyDeclared), publishers,
    subscriptions and services. (The bridge takes back its own check of parameter sets.)
    rclpy withdraws no read-only parameter: those stay declared, and the next configure
    takes them as they are (each is the same for the node's life: a -p, or the robot
    file's)."""

    def __init__(self, node: LifecycleNode) -> None:
        self.node = node
        self.parameters = set(node.list_parameters([], 0).names)
        self.publishers = list(node.publishers)
        self.subscriptions = list(node.subscriptions)
        self.services = list(node.services)

    def undo(self) -> None:
        node = self.node
        for name in set(node.list_parameters([], 0).names) - self.parameters:
            with contextlib.suppress(ParameterImmutableException):
                node.undeclare_parameter(name)
        for publisher in [p for p in node.publishers if p not in self.publishers]:
            node.destroy_publisher(publisher)
        for subscription in [s for s in node.subscriptions if s not in self.subscriptions]:
            node.destroy_subscription(subscription)
        for service in [s for s in node.services if s not in self.services]:
            node.destroy_service(service)


class _ManagedNode(LifecycleNode):
    def __init__(self, loop: asyncio.AbstractEventLoop, description: RobotDescription,
                 ports: dict[str, str], opening: Mapping[str, Any], bag: NodeBag | None,
                 stop: asyncio.Event, overrides: set[str]) -> None:
        super().__init__(NODE_NAME, start_parameter_services=False)
        self.loop = loop
        self.description = description
        self.ports = ports
        #: how Robot.open takes the boards (baud, wire_crc, allow_mismatch)
        self.opening = dict(opening)
        self.bag = bag
        self.stop = stop
        self.overrides = overrides
        self.executor_ref: Any = None
        self.robot: Robot | None = None
        self.bridge: RosBridge | None = None
        self.running: asyncio.Task[None] | None = None
        #: what the node had before the configure that made the bridge (cleanup's undo)
        self.mark: _NodeMark | None = None

    def _on_loop(self, coroutine: Coroutine[Any, Any, TransitionCallbackReturn]
                 ) -> TransitionCallbackReturn:
        future = asyncio.run_coroutine_threadsafe(coroutine, self.loop)
        try:
            return future.result(TRANSITION_TIMEOUT_S)
        except concurrent.futures.TimeoutError:
            future.cancel()
            self.get_logger().error(f"transition not done within {TRANSITION_TIMEOUT_S:g} s")
            return TransitionCallbackReturn.FAILURE

    # --- transitions (on the executor's thread) ------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._on_loop(self._configure())

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._on_loop(self._activate())

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._on_loop(self._deactivate())

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._on_loop(self._cleanup())

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = self._on_loop(self.shut_down())
        self.loop.call_soon_threadsafe(self.stop.set)
        return result

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._on_loop(self.shut_down())
        return TransitionCallbackReturn.SUCCESS

    # --- the same, on the asyncio loop ---------------------------------------------------

    async def _configure(self) -> TransitionCallbackReturn:
        log = self.get_logger()
        mark = _NodeMark(self)
        robot = Robot.open(self.description, self.ports, **self.opening)
        configured = False
        bridge: RosBridge | None = None
        try:
            try:
                await robot.start()
            except IdentityMismatch as exc:
                log.error(f"configure: {exc} (--allow-mismatch goes on)")
                return TransitionCallbackReturn.FAILURE
            except (RobotError, FpgalinkError) as exc:
                log.error(f"configure: boards not reached: {exc}")
                return TransitionCallbackReturn.FAILURE
            try:
                bridge = RosBridge(robot, self, self.loop, executor=self.executor_ref,
                                   bag=self.bag, managed=True, overrides=self.overrides)
                await bridge.declare_board_parameters()
            except (ParameterException, BadOverride, FpgalinkError) as exc:
                log.error(f"configure: {exc}")
                return TransitionCallbackReturn.FAILURE
            bridge.serve_parameters()
            if bridge.params.foxglove:
                log.warning(f"foxglove {bridge.params.foxglove!r}: no live view with "
                            "--lifecycle yet: ignored")
            configured = True
        finally:
            if not configured:  # failed, or out of time: as before it, to be tried again
                if bridge is not None:
                    bridge.withdraw()
                mark.undo()
                await robot.close()
        self.robot, self.bridge, self.mark = robot, bridge, mark
        log.info(f"configured: boards {', '.join(f'{b}={u}' for b, u in self.ports.items())}"
                 + (" (emulated robot)" if robot.truth() is not None else ""))
        return TransitionCallbackReturn.SUCCESS

    async def _activate(self) -> TransitionCallbackReturn:
        if self.bridge is None:
            return TransitionCallbackReturn.FAILURE
        self.bridge.active = True
        self.bridge.publish_latched()
        self.running = asyncio.ensure_future(self.bridge.run())
        self.running.add_done_callback(self._run_ended)
        self.get_logger().info("activated: publishing and taking commands")
        return TransitionCallbackReturn.SUCCESS

    def _run_ended(self, task: asyncio.Task[None]) -> None:
        if not task.cancelled() and task.exception() is not None:
            # A link that failed for good: said, and the node stays as it is (a manager
            # sees the error in the log and the boards' diagnostics no longer coming).
            self.get_logger().error(f"stopped: {task.exception()}")

    async def _deactivate(self) -> TransitionCallbackReturn:
        if self.bridge is None or self.robot is None:
            return TransitionCallbackReturn.FAILURE
        self.bridge.active = False
        await self._stop_running()
        self.robot.disable()
        self.get_logger().info("deactivated: boards disabled, publishing stopped")
        return TransitionCallbackReturn.SUCCESS

    async def _cleanup(self) -> TransitionCallbackReturn:
        if self.bridge is None or self.robot is None or self.mark is None:
            return TransitionCallbackReturn.FAILURE
        await self._stop_running()
        self.bridge.withdraw()
        self.mark.undo()
        await self.robot.close()
        self.robot = self.bridge = self.mark = None
        self.get_logger().info("cleaned up: boards closed, their parameters withdrawn")
        return TransitionCallbackReturn.SUCCESS

    async def _stop_running(self) -> None:
        if self.running is not None:
            self.running.cancel()
            await asyncio.gather(self.running, return_exceptions=True)
            self.running = None

    async def shut_down(self) -> TransitionCallbackReturn:
        """The boards closed (the shutdown transition's work, and SIGINT's)."""
        if self.bridge is not None:
            self.bridge.active = False
        await self._stop_running()
        if self.robot is not None:
            await self.robot.close()
            self.robot = None
        return TransitionCallbackReturn.SUCCESS


async def run_managed(description: RobotDescription, ports: dict[str, str],
                      opening: Mapping[str, Any], bag: NodeBag | None,
                      stop: asyncio.Event, overrides: set[str]) -> int:
    """The managed node until SIGINT/SIGTERM (``stop``) or its shutdown transition."""
    loop = asyncio.get_running_loop()
    node = _ManagedNode(loop, description, ports, opening, bag, stop, overrides)
    executor, thread = spin_in_thread(node)
    node.executor_ref = executor
    node.get_logger().info("up, unconfigured (--lifecycle): configure opens the boards")
    try:
        await stop.wait()
        await node.shut_down()
    finally:
        executor.shutdown(timeout_sec=1.0)
        thread.join(timeout=2.0)
        with contextlib.suppress(Exception):
            node.destroy_node()
    return 0
