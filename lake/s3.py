"""The S3 filesystem smspace opens s3:// URLs with: s3fs, with every request bounded in time.

botocore adds `Expect: 100-continue` to uploads, and aiohttp starts its read timeout only once the
body is sent: an endpoint that never answers the expectation held every PUT forever, whatever the
timeouts. The clients of this filesystem send bodies at once (each PUT carries its Content-MD5,
which the server checks). A subclass rather than a patch of botocore: other clients in the process
keep their defaults, and spawned workers rebuild the same filesystem from its pickle. Instances are
not shared through fsspec's cache: the endpoint and keys come from the environment, which a process
may change between two lakes.
"""

from __future__ import annotations

from botocore import handlers
from s3fs import S3FileSystem

from smspace.lake.store import is_unreachable


class BoundedS3FileSystem(S3FileSystem):
    retries = 1  # botocore retries (lake/store.py, s3_options); s3fs's own loop around it would multiply them
    unanswered = 0  # requests the endpoint left unanswered after every attempt (lake/store.py, remote_errors)
    last_unanswered: BaseException | None = None

    async def _call_s3(self, method, *akwarglist, **kwargs):
        """Counts what the endpoint left unanswered: s3fs and fsspec pass some such errors over
        (`isfile` is False, a parent listing's failure is ignored), and a command that goes on after
        a time-out outlives the bound the README promises."""
        try:
            return await super()._call_s3(method, *akwarglist, **kwargs)
        except Exception as e:
            if is_unreachable(e):
                self.last_unanswered = e
                self.unanswered += 1
            raise

    async def set_session(self, refresh: bool = False, kwargs: dict | None = None):
        client = await super().set_session(refresh=refresh, kwargs=kwargs or {})
        client.meta.events.unregister("before-call.s3", handlers.add_expect_header)
        return client
