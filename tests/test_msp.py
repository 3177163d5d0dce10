"""Issue 47's first brick: MSP v1 and v2 framing with their checksums, and the request/reply client the
INAV backend will speak through (over a real TCP socket here)."""

from __future__ import annotations

import socket
import struct
import threading

import pytest

from magline.core.links.msp import ERROR, REPLY
from magline.plugin import MspClient, MspParser, MspRefused, MspTimeout, crc8_dvb_s2
from magline.plugin import encode_msp_v1 as encode_v1
from magline.plugin import encode_msp_v2 as encode_v2


def test_the_checksums_are_the_protocols():
    # CRC-8/DVB-S2's published check value, and MSP_API_VERSION's v1 request as every MSP tool sends it
    assert crc8_dvb_s2(b"123456789") == 0xBC
    assert encode_v1(1) == bytes([0x24, 0x4D, 0x3C, 0x00, 0x01, 0x01])
    # MSP2_COMMON_SETTING for "magzero_x": flag 0, function 0x1003, the name and its NUL
    frame = encode_v2(0x1003, b"magzero_x\x00")
    assert frame[:8] == b"$X<" + bytes([0, 0x03, 0x10, 10, 0]) and frame[-1] == crc8_dvb_s2(frame[3:-1])
    with pytest.raises(ValueError, match="v2"):
        encode_v1(0x1003)


def test_the_parser_takes_frames_split_anywhere_skips_noise_and_drops_a_bad_checksum():
    stream = (b"\x00noise$" + encode_v1(102, bytes(range(18)), REPLY) + encode_v2(0x1003, b"\x01\x02", ERROR)
              + encode_v1(5, b"x", REPLY)[:-1] + b"\x00" + encode_v2(0x1004, b"", REPLY))
    parser = MspParser()
    frames = [f for i in range(0, len(stream), 3) for f in parser.feed(stream[i:i + 3])]
    assert [(f.version, f.direction, f.command, f.payload) for f in frames] == [
        (1, REPLY, 102, bytes(range(18))), (2, ERROR, 0x1003, b"\x01\x02"), (2, REPLY, 0x1004, b"")]
    assert parser.bad_frames == 1  # the v1 frame whose checksum was spoilt


class Board:
    """A TCP peer that answers each request from a table: a reply, an error reply, or nothing.  ``late``
    holds a command's first request for that many seconds before its answer leaves (a board busy writing
    its flash); ``asked`` counts the requests that came, per command."""

    def __init__(self, answers: dict[int, bytes | None], late: dict[int, float] | None = None) -> None:
        self.answers = answers
        self.late = dict(late or {})
        self.asked: dict[int, int] = {}
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.sending = threading.Lock()
        self.late_sent = threading.Event()  # a held answer has left
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        parser = MspParser()
        with conn:
            while data := conn.recv(1024):
                for frame in parser.feed(data):
                    self.asked[frame.command] = self.asked.get(frame.command, 0) + 1
                    answer = self.answers.get(frame.command, b"")
                    if callable(answer):
                        answer = answer(frame.payload)
                    if answer is None:
                        continue  # never answered
                    encode = encode_v2 if frame.version == 2 else encode_v1
                    if answer == b"!":
                        out = encode(frame.command, b"", ERROR)
                    else:  # a stale reply to another command first: the client must wait for its own
                        out = encode(99, b"old", REPLY) + encode(frame.command, answer, REPLY)
                    delay = self.late.pop(frame.command, 0.0)
                    threading.Timer(delay, self._send, (conn, out, True)).start() if delay else self._send(conn, out)

    def _send(self, conn: socket.socket, data: bytes, late: bool = False) -> None:
        with self.sending:
            conn.sendall(data)
        if late:
            self.late_sent.set()


def test_the_client_waits_for_its_own_reply_and_says_a_refusal_or_a_silence():
    board = Board({1: bytes([0, 2, 5]), 0x1003: b"\x00\x04", 250: b"!", 68: None})
    client = MspClient.connect(f"tcp:127.0.0.1:{board.port}", timeout_s=0.5)
    try:
        assert client.request(1) == bytes([0, 2, 5])
        assert client.request(0x1003, b"magzero_x\x00") == b"\x00\x04"  # a v2 function, sent as v2
        with pytest.raises(MspRefused, match="refused MSP command 250"):
            client.request(250)
        with pytest.raises(MspTimeout, match=r"no reply to MSP command 68 within 0\.5 s, sent 3 times"):
            client.request(68)
        assert board.asked[68] == 3 and client.resent == 2  # sent again twice before the link is called lost
        with pytest.raises(MspTimeout, match=r"no reply to MSP command 68 within 0\.5 s$"):
            client.request(68, resends=0)
        assert board.asked[68] == 4
    finally:
        client.close()
    with pytest.raises(ValueError, match="tcp:HOST:PORT or serial:DEV"):
        MspClient.connect("udp:127.0.0.1:5760")


def _setting_value(payload: bytes) -> bytes:
    """MSP2_COMMON_SETTING's answer on the test board: each setting's value is its name's length."""
    return struct.pack("<h", len(payload.split(b"\0")[0]))


def test_a_late_reply_is_taken_once_and_never_for_the_next_question():
    """The board answers the first read late (after the client's timeout), so the client sends it again and
    two replies come to one question.  The second must not be taken for the next read of another setting:
    MSP numbers no request, and that read would see the first setting's value."""
    board = Board({0x1003: _setting_value}, late={0x1003: 0.6})
    client = MspClient.connect(f"tcp:127.0.0.1:{board.port}", timeout_s=0.4)
    try:
        assert client.request(0x1003, b"align_mag\0") == struct.pack("<h", 9)
        assert client.resent == 1
        assert board.late_sent.wait(5.0)  # both answers to the first read have left the board
        assert client.request(0x1003, b"mag_declination\0") == struct.pack("<h", 15)
        assert client.request(0x1003, b"mag_calibration_time\0") == struct.pack("<h", 20)
        assert board.asked[0x1003] == 4 and client.resent == 1
    finally:
        client.close()
