"""Start-up errors reach /rosout, not only stderr (a launch file's user may only watch /rosout)."""
from rcl_interfaces.msg import Log
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

START = 60.0


def test_a_start_up_error_is_logged_to_rosout(ros):
    c = ros.client()
    got = []
    c.node.create_subscription(Log, '/rosout', got.append,
                               QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                          durability=DurabilityPolicy.TRANSIENT_LOCAL))
    # Discovery of this subscriber can take longer than the node's default 3 s budget when the
    # machine is loaded: give it 30 s here (the node leaves as soon as it has found the subscriber).
    emu = ros.start(params={'safe_duty': 70.0}, env={**ros.env, 'PCV_SIM_ROSOUT_LINGER': '30'})
    assert c.spin_until(lambda: any('invalid parameters: safe_duty: got 70.0' in m.msg for m in got), START), (
        emu.output(), [m.msg for m in got])
    assert emu.wait(START) == 2
    (log,) = [m for m in got if 'invalid parameters' in m.msg]
    assert log.name.endswith('valve.emulator') and log.level == Log.ERROR
