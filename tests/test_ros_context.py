"""The ros_context fixture (tests/conftest.py): a private, initialized context on a test domain."""
from im_bringup.testing import TEST_DOMAINS, worker_domains
import rclpy
from rclpy.node import Node


def test_context_is_private_initialized_and_on_a_test_domain(ros_context):
    assert ros_context.ok() and not rclpy.ok()         # the global context is left alone
    lo, hi = worker_domains()
    assert TEST_DOMAINS[0] <= lo <= ros_context.get_domain_id() <= hi <= TEST_DOMAINS[1]
    node = Node('ctx_probe', context=ros_context)
    try:
        assert node.context is ros_context
    finally:
        node.destroy_node()


def test_parallel_workers_draw_from_disjoint_domains(monkeypatch):
    """Under pytest-xdist (make test's -n 2) two tests running at once never share a domain."""
    monkeypatch.delenv('PYTEST_XDIST_WORKER', raising=False)
    assert worker_domains() == TEST_DOMAINS
    for count in (2, 3):
        monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', str(count))
        shares = []
        for i in range(count):
            monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{i}')
            shares.append(set(range(worker_domains()[0], worker_domains()[1] + 1)))
        assert all(len(s) >= 20 for s in shares)
        assert set.union(*shares) <= set(range(TEST_DOMAINS[0], TEST_DOMAINS[1] + 1))
        assert sum(len(s) for s in shares) == len(set.union(*shares))     # disjoint
