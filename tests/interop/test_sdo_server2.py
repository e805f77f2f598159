"""The second SDO server (0x1201): configured over the default server by one master, used by
a second python-canopen SDO client beside the first, on the release image (the CAN filter of
the emulated bxCAN included). Abort codes as in crates/canopen-slave/tests/sdo_server2.rs."""

import threading

import canopen

from rig import NMT_RESET_COMMUNICATION, NODE_ID, SDO_RX, SDO_TIMEOUT, SDO_TX, TPDO1

# Free identifiers: 0x680..0x6DF is outside CiA 301's restricted ranges.
SDO2_RX = 0x680 + NODE_ID
SDO2_TX = 0x6A0 + NODE_ID
NOT_VALID = 0x8000_0000


def second_client(rig) -> canopen.sdo.SdoClient:
    """An SDO client of the second server on the rig's network."""
    client = canopen.sdo.SdoClient(SDO2_RX, SDO2_TX, rig.node.object_dictionary)
    client.network = rig.network
    client.RESPONSE_TIMEOUT = SDO_TIMEOUT
    rig.network.subscribe(SDO2_TX, client.on_response)
    return client


def configure(rig) -> None:
    rig.write(0x1201, 1, SDO2_RX, 4)
    rig.write(0x1201, 2, SDO2_TX, 4)
    rig.write(0x1201, 3, 1, 1)


def params(rig) -> list:
    return [rig.read(0x1201, sub) for sub in (1, 2, 3)]


def no_answer_on_the_second(rig) -> None:
    mark = rig.frames.mark()
    rig.network.send_message(SDO2_RX, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    rig.frames.assert_none(lambda f: f.id == SDO2_TX, 0.4, since=mark, what="second replies")


def test_second_sdo_server_reads_and_writes_beside_the_default_one(rig):
    assert rig.read(0x1201, 0) == 3
    assert params(rig) == [NOT_VALID, NOT_VALID, 0]
    no_answer_on_the_second(rig)
    configure(rig)
    assert params(rig) == [SDO2_RX, SDO2_TX, 1]
    second = second_client(rig)
    mark = rig.frames.mark()
    # Expedited and segmented uploads, an expedited and a segmented download.
    assert int.from_bytes(second.upload(0x1000, 0), "little") == 0
    assert second.upload(0x1008, 0) == b"CNC handwheel"
    second.download(0x1017, 0, (700).to_bytes(2, "little"))
    assert rig.read(0x1017) == 700
    second.download(0x1017, 0, (900).to_bytes(2, "little"), force_segment=True)
    assert rig.read(0x1017) == 900
    assert int.from_bytes(second.upload(0x1201, 2), "little") == SDO2_TX
    # The second server's answers go out on 0x1201:2 only; the default server answered
    # only the default client's reads.
    replies = rig.frames.frames(SDO2_TX, since=mark)
    assert replies[0].data == bytes([0x43, 0x00, 0x10, 0x00, 0, 0, 0, 0])
    assert len(replies) == 1 + 3 + 1 + 2 + 1
    assert len(rig.frames.frames(SDO_TX, since=mark)) == 2
    # Its checks: in use by TPDO1, a restricted identifier, a valid entry's change.
    rig.write(0x1201, 1, NOT_VALID | SDO2_RX, 4)
    assert rig.write_abort(0x1201, 1, TPDO1.to_bytes(4, "little")) == 0x06040043
    assert rig.write_abort(0x1201, 1, SDO_RX.to_bytes(4, "little")) == 0x06090030
    rig.write(0x1201, 1, SDO2_RX, 4)
    assert rig.write_abort(0x1201, 1, (SDO2_RX + 1).to_bytes(4, "little")) == 0x06090030
    # Both ways: TPDO1, given up first, may not take the second server's identifier.
    rig.write(0x1800, 1, NOT_VALID | TPDO1, 4)
    assert rig.write_abort(0x1800, 1, SDO2_TX.to_bytes(4, "little")) == 0x06040043


def test_both_servers_at_once_and_a_reset_of_communication(rig):
    configure(rig)
    second = second_client(rig)
    # A segmented upload on the default server, with the second client's reads between its
    # segments.
    with rig.node.sdo.open(0x1008, 0, "rb") as stream:
        name = b""
        while chunk := stream.read(7):
            name += chunk
            assert int.from_bytes(second.upload(0x1017, 0), "little") == 1000
    assert name == b"CNC handwheel"
    # Both clients busy in their own threads: every transfer completes.
    errors = []

    def poll_second():
        try:
            for _ in range(20):
                assert int.from_bytes(second.upload(0x1201, 1), "little") == SDO2_RX
                assert second.upload(0x1009, 0) == b"STM32F103C8"
        except Exception as e:  # reported by the main thread
            errors.append(e)

    thread = threading.Thread(target=poll_second)
    thread.start()
    for _ in range(20):
        assert rig.node.sdo.upload(0x1008, 0) == b"CNC handwheel"
        assert rig.read(0x1018, 1) == 0
    thread.join()
    assert not errors, errors
    # Reset communication: 0x1201 back to its defaults, the second server gone.
    mark = rig.nmt(NMT_RESET_COMMUNICATION)
    rig.frames.wait_id(0x700 + NODE_ID, bytes([0]), since=mark)
    assert params(rig) == [NOT_VALID, NOT_VALID, 0]
    no_answer_on_the_second(rig)
