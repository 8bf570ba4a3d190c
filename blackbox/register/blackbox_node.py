"""What every black box's process does with its store writer: the vehicle's recorder
(blackbox.register.recorder_node) and the fleet's sync (blackbox.fleet.sync_node) alike.

It hands records and events to the writer thread without ever waiting; when the writer's queue
is full (a store call that does not return) the item is lost and a `blackbox_queue_overflow`
fault says so: at the first loss, then at most once per QUEUE_OVERFLOW_EVERY_S of the node's
clock, each with the running count, so that a stuck store neither goes unreported nor floods the
events. The writer's notices (store down, back, spool overflow, a refused document) are published
as events from the node's own thread; at teardown the writer gets `shutdown_flush_s` to write
what is queued, and the notices of that last flush are published too, before the bus closes.
"""

from __future__ import annotations

import math

from ares.core.messages import EventLevel
from ares.core.node import Node
from blackbox.register.recorder import StoreWriter, StoreWriterParams, store_writer
from blackbox.register.spool import Item
from blackbox.register.store.record_store import StoreSettings

QUEUE_OVERFLOW_EVERY_S = 10.0  # node clock; the running count makes the events in between redundant


class BlackboxNode(Node):
    """A node that writes a black box through a StoreWriter (its Params derive from StoreWriterParams)."""

    Params = StoreWriterParams
    writer: StoreWriter

    def start_writer(self, settings: StoreSettings, spool_name: str) -> None:
        """Make and start the writer (a spool left by an earlier run is flushed first)."""
        self.writer = store_writer(self.params, settings, spool_name)
        self.lost = 0
        self._overflow_reported_at = -math.inf
        if self.writer.spool.pending:
            self.log.info("%d items left in %s: flushing them first", len(self.writer.spool), self.writer.spool.path)
        self.writer.start()

    def submit(self, item: Item) -> None:
        """Queue one record or event for the store; never waits."""
        if self.writer.submit(item):
            return
        self.lost += 1
        now = self.clock.now()
        if now - self._overflow_reported_at >= QUEUE_OVERFLOW_EVERY_S:  # the first loss: at once
            self._overflow_reported_at = now
            self.event(
                "blackbox_queue_overflow",
                f"black-box writer queue full: {self.lost} items lost so far",
                EventLevel.FAULT,
                lost=self.lost,
            )

    def publish_notices(self) -> None:
        """What the writer's thread has said since the last call, as events."""
        for notice in self.writer.take_notices():
            self.event(notice.kind, notice.message, notice.level, **notice.data)

    def teardown(self) -> None:
        writer = getattr(self, "writer", None)
        if writer is None:  # setup did not get as far as the writer
            return
        writer.close(self.params.shutdown_flush_s)
        self.publish_notices()
        self.log.info("%s", writer.stopped_summary(self.lost))
