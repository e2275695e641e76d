import random

import pytest

pytest_plugins = ['im_bringup.testing']


@pytest.fixture(autouse=True)
def ros_domain_id(monkeypatch):
    """
    Run each test on a random ROS domain in 150-229 (``ROS_DOMAIN_ID``), returned as an int.

    Every tool runs on ``ROS_DOMAIN_ID`` as ROS 2 does (the in-process graph, the executables
    a test starts, their processes): here, not in the tools, tests are kept apart from each
    other and from the user's own graph on the shared machine.
    """
    from im_bringup.testing import TEST_DOMAINS
    domain = random.randint(*TEST_DOMAINS)
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    return domain


@pytest.fixture(scope='session', autouse=True)
def graph_key_file(tmp_path_factory):
    """
    Share one key file among the nodes built without a key of their own.

    Nodes built without a key of their own (``ros2 run`` style) share this session's key file
    instead of the user's ``~/.ros/im_drive/graph.key``.
    """
    import os
    from im_common import auth
    path = str(tmp_path_factory.mktemp('key') / 'graph.key')
    old = os.environ.get(auth.KEY_ENV)
    os.environ[auth.KEY_ENV] = path
    yield path
    if old is None:
        os.environ.pop(auth.KEY_ENV, None)
    else:
        os.environ[auth.KEY_ENV] = old


@pytest.fixture
def ros_context():
    """
    Return an initialized rclpy ``Context`` on a random DDS domain.

    The domain is in 150-229; the context is shut down afterwards.

    Every in-process ROS test takes its context from here instead of calling ``rclpy.init``
    itself, so no test shares the global context or a domain with another run on the machine.
    """
    import rclpy
    from rclpy.context import Context
    from im_bringup.testing import TEST_DOMAINS
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random.randint(*TEST_DOMAINS))
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)
