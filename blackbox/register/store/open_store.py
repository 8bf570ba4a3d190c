"""Which storage engine a store URI opens (blackbox.register.store.record_store describes what every engine offers).

Apart from blackbox.register.store.record_store because the engines import that interface: a chooser living beside
it would make the interface and its engines import each other.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime

from blackbox.register.store.record_store import RecordStore, StoreSettings, is_mongo, utc_now


def open_store(
    uri: str | None, now: Callable[[], datetime] = utc_now, settings: StoreSettings = StoreSettings()
) -> RecordStore:
    """`mongodb://...` or `mongodb+srv://...` -> MongoDB; anything else is the embedded store's
    file (default: settings.location())."""
    uri = uri or settings.location()
    # imported when chosen: an embedded store never pays for importing pymongo
    if is_mongo(uri):
        from blackbox.register.store.mongo_store import MongoStore

        return MongoStore(uri, now=now, settings=settings)
    from blackbox.register.store.sqlite_store import SqliteStore

    return SqliteStore(uri, now=now, settings=settings)
