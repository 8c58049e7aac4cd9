"""Schemathesis hooks for tests/test_api_fuzz.py (loaded by ``st run`` through SCHEMATHESIS_HOOKS): every
generated request carries the token and a control lease this run holds, so motion, I/O and session
requests reach the service instead of stopping at 401/409. The fuzzer itself may release or take the
lease; it is taken back (with force) whenever it is no longer ours."""

from __future__ import annotations

import os
from typing import Any

import httpx
import schemathesis

BASE_URL = os.environ.get("FUZZ_BASE_URL", "")
TOKEN = os.environ.get("FUZZ_TOKEN", "")
CLIENT = "fuzz"


@schemathesis.auth(refresh_interval=None)
class TokenAndLease:
    def __init__(self) -> None:
        self.http = httpx.Client(base_url=BASE_URL, timeout=10.0)
        self.lease_id = ""

    def get(self, case: Any, ctx: Any) -> dict[str, str]:
        auth = {"Authorization": f"Bearer {TOKEN}"}
        held = self.http.get("/api/lease").json()
        if self.lease_id and held.get("held") and held.get("client") == CLIENT:
            r = self.http.post("/api/lease/renew", headers={**auth, "X-Lease-Id": self.lease_id})
            if r.status_code == 200:
                return {**auth, "X-Lease-Id": self.lease_id}
        r = self.http.post("/api/lease", json={"client": CLIENT, "force": True}, headers=auth)
        r.raise_for_status()
        self.lease_id = r.json()["lease_id"]
        return {**auth, "X-Lease-Id": self.lease_id}

    def set(self, case: Any, data: dict[str, str], ctx: Any) -> None:
        case.headers = {**(case.headers or {}), **data}
