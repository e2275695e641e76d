import random

import pytest

pytest_plugins = ['im_bringup.testing']

#: DDS domains the in-process tests draw from (shared machine: keep clear of the default 0)
TEST_DOMAINS = (150, 229)


@pytest.fixture
def ros_context():
    """An initialized rclpy ``Context`` on a random DDS domain in 150-229, shut down afterwards.

    Every in-process ROS test takes its context from here instead of calling ``rclpy.init``
    itself, so no test shares the global context or a domain with another run on the machine.
    """
    import rclpy
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random.randint(*TEST_DOMAINS))
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)
