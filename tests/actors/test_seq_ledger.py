"""The durable sequence ledger: a restarted actor continues numbering after the last number
its predecessor wrote, so anything that predecessor never delivered becomes a counted gap."""

from __future__ import annotations

from actors.seq_ledger import SeqLedger


def test_restart_continues_after_the_last_recorded_number(tmp_path):
    first = SeqLedger(str(tmp_path), actor_id=3)
    assert first.next_seq() == 0
    for seq in range(7):
        first.record(seq)
    first.close()  # the process dies; the file stays
    second = SeqLedger(str(tmp_path), actor_id=3)
    assert second.next_seq() == 7
    assert SeqLedger(str(tmp_path), actor_id=4).next_seq() == 0


def test_without_a_directory_numbering_starts_at_zero(tmp_path):
    ledger = SeqLedger("", actor_id=0)
    ledger.record(5)
    assert ledger.next_seq() == 0
