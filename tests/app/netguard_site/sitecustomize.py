"""Loaded by every Python process started with this folder on PYTHONPATH: records network attempts.

An audit hook (PEP 578) appends one line to ``$NETGUARD_LOG`` for every DNS lookup of a
host that is not local and every connect or send to an address outside loopback.
It sees this interpreter only (not non-Python children such as wandb-core).
"""

import ipaddress
import os
import sys

_LOG = os.environ.get("NETGUARD_LOG")
_LOCAL_NAMES = {None, "", "localhost", "localhost.localdomain"}
_LOOKUPS = {"socket.getaddrinfo", "socket.gethostbyname", "socket.gethostbyname_ex", "socket.gethostbyaddr"}
_SENDS = {"socket.connect", "socket.sendto", "socket.sendmsg"}


def _is_local(host) -> bool:
    if isinstance(host, bytes):
        host = host.decode(errors="replace")
    if host in _LOCAL_NAMES:
        return True
    try:
        return ipaddress.ip_address(str(host).split("%")[0]).is_loopback
    except ValueError:
        return False


def _record(event: str, detail) -> None:
    with open(_LOG, "a") as log:
        log.write(f"{event} {detail!r}\n")


def _hook(event: str, args) -> None:
    if event in _LOOKUPS and not _is_local(args[0]):
        _record(event, args[0])
    elif event in _SENDS:
        address = args[1] if len(args) > 1 else None
        if isinstance(address, tuple) and not _is_local(address[0]):
            _record(event, address)


if _LOG:
    sys.addaudithook(_hook)
