"""The AX-12A emulator, driven by the real dynamixel-sdk through its pseudo-terminal."""

import os
import threading
import time

import pytest

dxl = pytest.importorskip("dynamixel_sdk")
from dynamixel_sdk import (  # noqa: E402
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    DXL_HIBYTE,
    DXL_LOBYTE,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from simbench.servo_sim import (  # noqa: E402
    ERR_ANGLE,
    ERR_CHECKSUM,
    ERR_INSTRUCTION,
    ERR_RANGE,
    Faults,
    ServoSim,
    cli,
    decode_error,
    instruction_packet,
    status_packet,
)


@pytest.fixture(autouse=True)
def patient_sdk(monkeypatch):
    """The raw SDK gives up on a reply after 2 x LATENCY_TIMER + 2 ms (34 ms); on a loaded machine
    the emulator's thread can take longer than that, and a correct reply would read as a timeout.
    Waiting 100 ms per LATENCY_TIMER keeps these checks about what comes back, not about the
    machine's load."""
    import dynamixel_sdk.port_handler as ph

    monkeypatch.setattr(ph, "LATENCY_TIMER", 100)


@pytest.fixture
def bus():
    with ServoSim([1, 2, 3], time_scale=20.0) as sim:
        port = PortHandler(sim.port_path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        yield sim, port, PacketHandler(1.0)
        port.closePort()


def test_ping_read_and_model_number(bus):
    sim, port, ph = bus
    for i in (1, 2, 3):
        assert ph.ping(port, i) == (12, COMM_SUCCESS, 0)
    assert ph.ping(port, 9)[1] == COMM_RX_TIMEOUT
    assert ph.read2ByteTxRx(port, 2, 36) == (512, COMM_SUCCESS, 0)
    data, comm, err = ph.readTxRx(port, 1, 0, 10)  # model(2) fw id baud delay cw(2) ccw(2)
    assert comm == COMM_SUCCESS and data[3] == 1 and data[4] == 1 and data[8:10] == [0xFF, 0x03]


def test_write_range_and_angle_limit_errors(bus):
    sim, port, ph = bus
    assert ph.write2ByteTxRx(port, 1, 30, 2000) == (COMM_SUCCESS, ERR_RANGE)
    # present position is read-only
    assert ph.write2ByteTxRx(port, 1, 36, 100) == (COMM_SUCCESS, ERR_RANGE)
    assert ph.write2ByteTxRx(port, 2, 8, 600) == (COMM_SUCCESS, 0)  # CCW limit 600
    comm, err = ph.write2ByteTxRx(port, 2, 30, 700)
    assert err & ERR_ANGLE and "Angle limit" in ph.getRxPacketError(err)
    assert ph.read2ByteTxRx(port, 2, 30)[0] == 512  # the goal was refused ...
    assert ph.ping(port, 2)[2] & ERR_ANGLE  # ... and the error stays latched until a valid goal
    assert ph.write2ByteTxRx(port, 2, 30, 550) == (COMM_SUCCESS, 0)
    assert ph.ping(port, 2)[2] == 0
    assert decode_error(ERR_ANGLE | ERR_RANGE) == ["angle limit error", "range error"]
    refused = sim.writes(address=30, accepted=False)
    assert {(e["id"], e["value"]) for e in refused} == {(1, 2000), (2, 700)}


def test_sync_write_moves_at_the_set_speed(bus):
    sim, port, ph = bus
    g = GroupSyncWrite(port, ph, 30, 4)
    # 100 speed units = 11.1 rpm = 66.6 deg/s; 100 position units = 29.3 deg -> 0.44 s real, 22 ms
    # at x20
    for i, goal in ((1, 612), (2, 412), (3, 512)):
        g.addParam(i, [DXL_LOBYTE(goal), DXL_HIBYTE(goal), DXL_LOBYTE(100), DXL_HIBYTE(100)])
    t0 = time.monotonic()
    assert g.txPacket() == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 1, 24)[0] == 1  # writing a goal turns torque on
    while ph.read1ByteTxRx(port, 1, 46)[0] == 1:
        time.sleep(0.002)
    dt = time.monotonic() - t0
    assert 0.015 < dt < 0.08, dt
    assert ph.read2ByteTxRx(port, 1, 36)[0] == 612 and ph.read2ByteTxRx(port, 2, 36)[0] == 412
    log = sim.writes()
    assert [(e["instruction"], e["id"], e["register"], e["value"]) for e in log] == [
        ("SYNC_WRITE", 1, "goal_position", 612),
        ("SYNC_WRITE", 1, "moving_speed", 100),
        ("SYNC_WRITE", 2, "goal_position", 412),
        ("SYNC_WRITE", 2, "moving_speed", 100),
        ("SYNC_WRITE", 3, "goal_position", 512),
        ("SYNC_WRITE", 3, "moving_speed", 100),
    ]


def test_torque_off_stops_motion_and_reg_write_action(bus):
    sim, port, ph = bus
    assert ph.regWriteTxRx(port, 3, 30, 2, [DXL_LOBYTE(700), DXL_HIBYTE(700)]) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 3, 44)[0] == 1 and ph.read2ByteTxRx(port, 3, 30)[0] == 512
    ph.action(port, 254)  # broadcast ACTION: no reply
    time.sleep(0.01)
    assert ph.read2ByteTxRx(port, 3, 30)[0] == 700 and ph.read1ByteTxRx(port, 3, 44)[0] == 0
    assert ph.write1ByteTxRx(port, 3, 24, 0) == (COMM_SUCCESS, 0)
    p1 = ph.read2ByteTxRx(port, 3, 36)[0]
    time.sleep(0.05)
    assert ph.read2ByteTxRx(port, 3, 36)[0] == p1 and ph.read1ByteTxRx(port, 3, 46)[0] == 0
    # ACTION without a registered write is an instruction error
    port.writePort(instruction_packet(3, 0x05))
    time.sleep(0.01)
    assert port.readPort(6)[4] == ERR_INSTRUCTION


def test_packets_in_pieces_and_bad_checksums(bus):
    sim, port, ph = bus
    pkt = instruction_packet(2, 0x02, bytes([36, 2]))  # READ present position
    for b in pkt:  # one byte at a time
        port.writePort(bytes([b]))
        time.sleep(0.002)
    time.sleep(0.01)
    assert port.readPort(64) == status_packet(2, 0, bytes([0x00, 0x02]))
    bad = bytearray(instruction_packet(1, 0x03, bytes([25, 1])))
    bad[-1] ^= 0xFF
    port.writePort(b"\x00\x13" + bytes(bad))  # leading garbage, then a packet with a wrong checksum
    time.sleep(0.01)
    reply = port.readPort(64)
    assert reply[2] == 1 and reply[4] == ERR_CHECKSUM
    assert ph.read1ByteTxRx(port, 1, 25)[0] == 0  # not executed


def test_faults_drop_corrupt_unplug():
    with ServoSim(
        [1, 2], faults=Faults(drop_replies=1, corrupt_replies=1, unplugged_ids={2})
    ) as sim:
        port = PortHandler(sim.port_path)
        ph = PacketHandler(1.0)
        port.openPort()
        assert ph.read2ByteTxRx(port, 1, 36)[1] == COMM_RX_TIMEOUT
        assert ph.read2ByteTxRx(port, 1, 36)[1] == COMM_RX_CORRUPT
        assert ph.read2ByteTxRx(port, 1, 36)[1] == COMM_SUCCESS
        assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
        g = GroupSyncWrite(port, ph, 30, 2)
        g.addParam(1, [0, 2])
        g.addParam(2, [0, 2])
        g.txPacket()
        time.sleep(0.01)
        assert [e["id"] for e in sim.writes(address=30)] == [1]  # the unplugged servo heard nothing
        assert [f["fault"] for f in sim.fault_log] == ["dropped reply", "corrupt checksum"]
        port.closePort()


def test_wrong_baud_rate_is_silent():
    with ServoSim([1]) as sim:
        port = PortHandler(sim.port_path)
        ph = PacketHandler(1.0)
        port.openPort()
        assert port.setBaudRate(57600)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        assert port.setBaudRate(1_000_000)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        port.closePort()


def test_stops_cleanly_and_cli(tmp_path, capsys):
    sim = ServoSim([1]).start()
    thread = sim._thread
    sim.stop()
    assert not thread.is_alive() and sim.master is None
    link = tmp_path / "ttyDXL"
    logf = tmp_path / "log.json"
    result = {}

    def run():
        result["rc"] = cli(
            ["--ids", "1-3", "--link", str(link), "--duration", "0.6", "--log", str(logf)]
        )

    t = threading.Thread(target=run)
    t.start()
    for _ in range(100):
        if link.exists():
            break
        time.sleep(0.01)
    port = PortHandler(str(link))
    port.openPort()
    ph = PacketHandler(1.0)
    assert ph.ping(port, 3)[0] == 12
    assert ph.write2ByteTxRx(port, 3, 30, 600) == (COMM_SUCCESS, 0)
    port.closePort()
    t.join()
    assert result["rc"] == 0 and not os.path.exists(link)
    out = capsys.readouterr().out
    assert "IDs 1,2,3" in out and "1 register writes" in out
    assert '"value": 600' in logf.read_text()
    assert cli(["--ids", "x"]) == 2


def test_short_reply_crashes_the_sdk_but_not_the_bus():
    """dynamixel-sdk 4.1 indexes a too-short READ reply (what a late PING reply looks like to the
    READ of its P1 ping) and raises IndexError; the actuator's Bus counts it as a corrupted reply
    and retries."""
    from nodes.actuators._bus import Bus

    with ServoSim([1], faults=Faults(short_replies=1)) as sim:
        port = PortHandler(sim.port_path)
        port.openPort()
        with pytest.raises(IndexError):
            PacketHandler(1.0).read2ByteTxRx(port, 1, 36)
        port.closePort()
        sim.set_faults(short_replies=2)
        bus = Bus(sim.port_path, 1_000_000, retries=2, t0=time.monotonic(), late_window_ms=50)
        bus.open()
        assert bus.read(1, 36, 2, "read of the present position") == 512
        bus.close()
        assert bus.n_retries == 2 and all("corrupted status packet" in e for e in bus.events)
