"""The PC's own LAN IPv4 addresses, so the user knows what to type into the phone's app.

Only local interface queries: ``ip -4 -o addr`` where it exists (Linux), the address the system
would send from (a UDP socket "connected" to a private address: no packet is sent; Windows and
macOS) and the host name's addresses.
"""

from __future__ import annotations

import ipaddress
import shutil
import socket
import subprocess


def _from_hostname() -> list[str]:
    try:
        infos = socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)
    except OSError:
        return []
    return [info[4][0] for info in infos]


def parse_ip_addr_output(text: str) -> list[str]:
    """Addresses from ``ip -4 -o addr`` output lines like
    ``2: eth0    inet 192.168.1.23/24 brd 192.168.1.255 scope global eth0``."""
    out = []
    for line in text.splitlines():
        fields = line.split()
        if "inet" in fields:
            index = fields.index("inet")
            if index + 1 < len(fields):
                out.append(fields[index + 1].split("/")[0])
    return out


def _from_ip_command() -> list[str]:
    ip = shutil.which("ip")
    if ip is None:
        return []
    try:
        done = subprocess.run([ip, "-4", "-o", "addr", "show"], capture_output=True, text=True,
                              timeout=2.0, check=False)
    except (OSError, subprocess.SubprocessError):
        return []
    return parse_ip_addr_output(done.stdout)


def _from_route() -> list[str]:
    """The address of the interface the system routes LAN traffic through (connect() on a UDP
    socket picks it without sending anything)."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.connect(("10.255.255.255", 1))
        return [probe.getsockname()[0]]
    except OSError:
        return []
    finally:
        probe.close()


def lan_ipv4_addresses() -> list[str]:
    """LAN IPv4 addresses of this machine, private ones first, loopback last.

    Always returns at least one address ("127.0.0.1" when nothing else is found).
    """
    found: list[str] = []
    for address in _from_ip_command() + _from_route() + _from_hostname():
        try:
            parsed = ipaddress.IPv4Address(address)
        except ValueError:
            continue
        if parsed.is_unspecified or parsed.is_multicast or parsed.is_link_local:
            continue
        if address not in found:
            found.append(address)

    def rank(address: str) -> tuple[int, str]:
        parsed = ipaddress.IPv4Address(address)
        return (2 if parsed.is_loopback else 0 if parsed.is_private else 1, address)

    found.sort(key=rank)
    return found or ["127.0.0.1"]
