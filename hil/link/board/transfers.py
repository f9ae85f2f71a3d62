"""Calibration transfers of one board session, sans-IO: transfer ids, uploads cut into fragments, and
downloads (:class:`Download`) reassembled from the board's fragments, each answered once.

:class:`~hil.link.board.session.Session` owns one :class:`CalibrationTransfers`; it sends the commands
and answers, this keeps the transfers' state.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from protocol.calibration import Reassembler, UnitCalibration, fragment
from protocol.errors import CalibrationError, HilError, LinkError, LinkTimeout, ProtocolError
from protocol.frame import Frame
from protocol.messages import Ack, CalibrationData, CalibrationRequest, Nack, NackReason
from protocol.reliable import AnswerCache, Command, answer_for


@dataclass(eq=False)
class Download:
    """A calibration download in progress (``Session.start_download``); ``done`` once it completed or
    failed, then :meth:`result` gives the unit's calibration or raises why not.

    Each download reassembles its own fragments (``reassembler``): one shared by the session's downloads
    held the last set it completed, and a later download that drew the same unit and transfer id (transfer
    ids wrap after 256 transfers, uploads included) of the same set took every fragment for a repeat of
    that one, acknowledged it and never completed; a download started while another ran wiped the other's
    fragments, already acknowledged and never sent again."""

    unit: int
    transfer_id: int
    request: Command
    data: bytes | None = None
    error: HilError | None = None
    reassembler: Reassembler = field(default_factory=Reassembler, repr=False)
    heard_at: float = 0.0  # host time (s) of its request, then of its last fragment heard

    @property
    def done(self) -> bool:
        return self.data is not None or self.error is not None

    def result(self) -> UnitCalibration:
        if self.error is not None:
            raise self.error
        if self.data is None:
            raise ProtocolError(f"calibration download of unit {self.unit} is still running")
        return UnitCalibration.from_bytes(self.data, source=f"board unit {self.unit}")


class CalibrationTransfers:
    """The transfers of one session: the next transfer id, the downloads waiting for fragments (by unit
    and transfer id), each reassembling its own, and the answers already given (a retransmitted fragment
    is answered again, not fed twice)."""

    def __init__(self) -> None:
        self._answers = AnswerCache()
        self._downloads: dict[tuple[int, int], Download] = {}
        self._transfer_id = 0

    def next_transfer_id(self) -> int:
        self._transfer_id = (self._transfer_id + 1) & 0xFF
        return self._transfer_id

    def upload_fragments(self, unit: int, calibration: UnitCalibration) -> list[CalibrationData]:
        """The CalibrationData fragments that upload ``calibration`` to ``unit``, with a new transfer id."""
        return fragment(unit, self.next_transfer_id(), calibration.to_bytes())

    def track(self, unit: int, transfer_id: int, request: Command) -> Download:
        """A download just requested (``request`` is its CalibrationRequest): wait for its fragments."""
        download = Download(unit, transfer_id, request, heard_at=request.sent_at)
        stale = self._downloads.get((unit, transfer_id))
        if stale is not None and not stale.done:  # 256 transfers ago, never finished: its fragments are gone
            stale.error = LinkError(
                f"calibration download of unit {unit}: transfer id {transfer_id} reused by a newer download"
            )
        self._downloads[(unit, transfer_id)] = download
        return download

    def abandon(self, why: str) -> None:
        """The link is gone: every running download fails with :class:`LinkError`; partial data is dropped."""
        for download in self._downloads.values():
            if not download.done:
                download.error = LinkError(f"calibration download of unit {download.unit}: {why}")
        self._downloads.clear()

    def cancel(self, download: Download, error: HilError) -> None:
        """The caller stopped waiting for ``download`` (its timeout): it fails with ``error`` and is no
        longer tracked, so its late fragments are refused (``BAD_STATE``: the board learns nobody takes
        them) instead of acknowledged into a download nobody reads — the board then took the transfer
        for delivered while the caller was told it timed out, and each such download stayed held."""
        key = (download.unit, download.transfer_id)
        if self._downloads.get(key) is download:
            del self._downloads[key]
        if not download.done:
            download.error = error

    def idle_since(self) -> float | None:
        """The host time (s) the longest-silent running download last heard of its board (None: none
        whose request the board has answered: until then the request's retries keep time)."""
        return min(
            (since for d in self._downloads.values() if (since := _heard(d)) is not None), default=None
        )

    def expire(self, now: float, idle_s: float) -> None:
        """Fail the downloads no fragment has come for in ``idle_s`` s since their request was answered
        or their last fragment (:class:`LinkTimeout`): the board gave up on them (it abandons a fragment
        the host's answers never reach after a few tries) or never began, and a caller without a timeout
        of its own — the calibration cycle — waited for ever on a link that was otherwise up."""
        for download in list(self._downloads.values()):
            since = _heard(download)
            if since is None or now - since < idle_s:
                continue
            self.cancel(
                download,
                LinkTimeout(
                    f"calibration download of unit {download.unit}: no fragment from the board for "
                    f"{now - since:.2f} s (it gave the transfer up)"
                ),
            )

    @property
    def running(self) -> int:
        """How many downloads wait for fragments."""
        return len(self._downloads)

    def request_failed(self, cmd: Command) -> None:
        """A CalibrationRequest was refused or never answered: its download fails with the reason."""
        message: CalibrationRequest = cmd.message
        key = (message.unit, message.transfer_id)
        download = self._downloads.get(key)
        if download is None or download.request is not cmd:
            return  # its download was already replaced by a newer one of the same transfer id
        del self._downloads[key]
        if not download.done:
            try:
                cmd.result()
            except HilError as exc:
                download.error = exc

    def answer(self, frame: Frame, now: float) -> Ack | Nack:
        """The answer to a fragment of a download (B→H, reliable) heard at ``now`` (s), feeding it to the
        reassembler once."""
        msg: CalibrationData = frame.message
        download = self._downloads.get((msg.unit, msg.transfer_id))
        if download is not None:
            download.heard_at = now  # a retry of a fragment too: the board is still sending
        answer = self._answers.lookup(frame)
        if answer is None:
            refused: NackReason | None = None
            if download is None or download.done:
                refused = NackReason.BAD_STATE  # nothing asked for this transfer
            else:
                try:
                    done = download.reassembler.feed(msg)
                except CalibrationError as exc:
                    download.error = exc
                    refused = NackReason.BAD_CALIBRATION
                else:
                    if done is not None:
                        download.data = done[1]
                        del self._downloads[(msg.unit, msg.transfer_id)]
            answer = answer_for(frame, refused)
            self._answers.remember(frame, answer)
        return answer


def _heard(download: Download) -> float | None:
    """When ``download`` last heard of its board (s, host time): its request's answer or its last fragment,
    whichever is later; None while its request is unanswered."""
    settled = download.request.settled_at
    if not download.request.done or settled is None:
        return None
    return max(download.heard_at, settled)
