"""The ros_context fixture (tests/conftest.py): a private, initialized context on a test domain."""
from im_bringup.testing import TEST_DOMAINS
import rclpy
from rclpy.node import Node


def test_context_is_private_initialized_and_on_a_test_domain(ros_context):
    assert ros_context.ok() and not rclpy.ok()         # the global context is left alone
    assert TEST_DOMAINS[0] <= ros_context.get_domain_id() <= TEST_DOMAINS[1]
    node = Node('ctx_probe', context=ros_context)
    try:
        assert node.context is ros_context
    finally:
        node.destroy_node()
