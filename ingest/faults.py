"""Whose fault a failure to store is: the ship's (its disk, its database) or the message's.

The ship's own failures (a full or read-only disk, a locked or unreachable database) are no
message's doing: the ingest never quarantines a message for them (`ingest.commit`), tells the
module to resend until it works (``internal_error``), and keeps results it could not store to
store them later (`ingest.results`).
"""

from __future__ import annotations

import errno

from storage.db import database_unusable

#: What a failed write says when the disk, not the data, is at fault.
_SHIP_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EACCES, errno.EPERM, errno.EMFILE}


def ships_fault(exc: BaseException) -> bool:
    """Whether a failure to store is the ship's own (disk, database), whatever the message held.

    A full, read-only or failing disk (OSError with such an errno, anywhere in the exception's
    chain), a database that cannot be used now (`storage.db.database_unusable`: locked, disk
    full, connection lost) or no memory.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in _SHIP_ERRNOS:
            return True
        if isinstance(e, MemoryError) or database_unusable(e):
            return True
        e = e.__cause__ or e.__context__
    return False
