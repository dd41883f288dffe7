"""What every eit_skin node does the same way: read-only parameters, diagnostics, main()."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from eit_skin.patch import PatchError

#: (name, default, description) of a node parameter; the default fixes its type.
ParameterTable = list[tuple[str, object, str]]


def declare_read_only(node: Node, table: ParameterTable) -> dict[str, object]:
    """Declare every parameter with a descriptor (read once at start) and return the values."""
    for name, default, description in table:
        node.declare_parameter(
            name, default, ParameterDescriptor(description=description, read_only=True)
        )
    return {name: node.get_parameter(name).value for name, _, _ in table}


def diagnostic_status(
    level: int, name: str, message: str, hardware_id: str, values: dict[str, str]
) -> DiagnosticStatus:
    """A ``diagnostic_msgs/DiagnosticStatus`` (level 0 OK, 1 WARN, 2 ERROR)."""
    return DiagnosticStatus(
        level=bytes([level]),
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in values.items()],
    )


def run_node(make_node: Callable[[], Node], executable: str, args: list[str] | None) -> int:
    """Spin a node until shutdown (Ctrl-C: exit 0); a bad configuration exits 2 with one line."""
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (PatchError, FileNotFoundError, KeyError, ValueError) as error:
        print(f"{executable}: refusing to start: {error}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
