"""The console's users: names, roles and passwords kept as salted hashes (issue 23 §3).

A password is kept as ``scrypt$N$r$p$SALT$HASH`` (standard library ``hashlib.scrypt``, a
random 16-byte salt per user, the parameters recorded with each hash so that stronger ones
can be used later without breaking the old hashes); it is checked by recomputing the hash and
comparing in constant time (``hmac.compare_digest``). The password itself is never stored,
logged or shown. Users live in the results store (``users`` table, store/people.py);
docs/decisions/0063-console-users.md says why.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets

from vts_hw.errors import UsageError
from vts_hw.store.records import ROLES

#: scrypt's cost (N), block size (r) and parallelism (p): 32 MiB and ~0.1 s per hash
SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**15, 8, 1
SALT_BYTES, HASH_BYTES = 16, 32
MIN_PASSWORD = 8
MAX_PASSWORD = 1024
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
RESERVED = ("local",)  # the console's name for the person at 127.0.0.1 without users


def _b64(b: bytes) -> str:
    return base64.b64encode(b).decode("ascii")


def _scrypt(password: str, salt: bytes, n: int, r: int, p: int, dklen: int) -> bytes:
    return hashlib.scrypt(
        password.encode("utf-8"), salt=salt, n=n, r=r, p=p, dklen=dklen, maxmem=2 * 128 * r * n + (1 << 20)
    )


def hash_password(password: str) -> str:
    """The stored form of ``password``: scrypt with a fresh salt and the parameters it used."""
    salt = secrets.token_bytes(SALT_BYTES)
    digest = _scrypt(password, salt, SCRYPT_N, SCRYPT_R, SCRYPT_P, HASH_BYTES)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def verify_password(stored: str, password: str) -> bool:
    """True when ``password`` is the one ``stored`` was made from (constant-time compare); False
    for a wrong one and for a stored value that is not one of our hashes."""
    try:
        kind, n_text, r_text, p_text, salt, digest = stored.split("$")
        if kind != "scrypt":
            return False
        n, r, p = int(n_text), int(r_text), int(p_text)
        if not (2 <= n <= 2**20 and 1 <= r <= 32 and 1 <= p <= 16):
            return False
        salt_b, want = base64.b64decode(salt, validate=True), base64.b64decode(digest, validate=True)
        if len(want) != HASH_BYTES or len(salt_b) < 8:
            return False
    except (ValueError, AttributeError):
        return False
    got = _scrypt(password, salt_b, n, r, p, len(want))
    return hmac.compare_digest(got, want)


#: a hash of nothing anyone knows, checked when the user does not exist, so that a wrong name
#: costs the same time as a wrong password (the login page says the same for both)
_DUMMY = None


def dummy_check(password: str) -> bool:
    global _DUMMY
    if _DUMMY is None:
        _DUMMY = hash_password(secrets.token_urlsafe(16))
    verify_password(_DUMMY, password)
    return False


def check_name(name: str) -> str:
    if not NAME.match(name or ""):
        raise UsageError(
            f"user name {name!r} is not allowed: use 1 to 64 letters, digits, '.', '_' or '-', "
            "starting with a letter or digit"
        )
    if name.lower() in RESERVED:
        raise UsageError(
            f"user name {name!r} is reserved (the console's name for the person at this "
            "machine when there are no users): pick another"
        )
    return name


def check_role(role: str) -> str:
    if role not in ROLES:
        raise UsageError(f"role {role!r} is not one of {', '.join(ROLES)}")
    return role


def check_password(password: str) -> str:
    if len(password) < MIN_PASSWORD or not password.strip():
        raise UsageError(f"the password is too short: give at least {MIN_PASSWORD} characters")
    if len(password) > MAX_PASSWORD:
        raise UsageError(f"the password is too long: at most {MAX_PASSWORD} characters")
    return password


def add_user(store, name: str, role: str, password: str) -> str:
    """Add ``name`` with ``role`` and ``password`` (hashed) to the store, or enable a disabled
    one again; the sentence to print. UsageError (exit 2) for bad input or a user already there."""
    check_name(name)
    check_role(role)
    check_password(password)
    try:
        user, how = store.put_user(name, role, hash_password(password))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return f"user {user.name} ({user.role}) {how} in {store.url}"


def remove_user(store, name: str) -> str:
    """Disable ``name`` (kept, so the actions logged under it stay its own); the sentence to print."""
    try:
        user = store.disable_user(name)
    except KeyError:
        raise UsageError(f"no user {name!r} in {store.url}") from None
    return f"user {user.name} disabled in {store.url}: it can no longer log in (its actions keep its name)"


def list_users(store) -> list[dict]:
    """The users as plain data (never the hash)."""
    return [
        {
            "name": u.name,
            "role": u.role,
            "active": u.active,
            "created": u.created,
            "changed": u.changed,
            "disabled": u.disabled,
        }
        for u in store.users()
    ]


__all__ = [
    "hash_password",
    "verify_password",
    "dummy_check",
    "add_user",
    "remove_user",
    "list_users",
    "check_name",
    "check_role",
    "check_password",
    "ROLES",
]
