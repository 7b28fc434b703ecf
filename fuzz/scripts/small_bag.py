#!/usr/bin/env python3
"""Cuts a small, valid ROS 1 bag (format 2.0) out of a real one: the connections and the first
messages of each connection, in one chunk (none, bz2), with a fresh index. Fuzz seeds only.

usage: small_bag.py IN.bag OUT.bag MESSAGES_PER_CONNECTION [none|bz2]
"""
import bz2
import struct
import sys

MAGIC = b"#ROSBAG V2.0\n"


def records(buf, at, end):
    while at + 4 <= end:
        hlen = struct.unpack_from("<I", buf, at)[0]
        hdr = buf[at + 4:at + 4 + hlen]
        dlen = struct.unpack_from("<I", buf, at + 4 + hlen)[0]
        data = buf[at + 8 + hlen:at + 8 + hlen + dlen]
        yield fields(hdr), hdr, data
        at += 8 + hlen + dlen


def fields(hdr):
    out, p = {}, 0
    while p + 4 <= len(hdr):
        n = struct.unpack_from("<I", hdr, p)[0]
        k, _, v = hdr[p + 4:p + 4 + n].partition(b"=")
        out[k] = v
        p += 4 + n
    return out


def header(d):
    b = b""
    for k, v in d.items():
        f = k + b"=" + v
        b += struct.pack("<I", len(f)) + f
    return b


def record(d, data):
    h = header(d)
    return struct.pack("<I", len(h)) + h + struct.pack("<I", len(data)) + data


def slim(conn):
    """Empties the connection's message definition: the readers go by type name, and the
    definitions (kilobytes of text) would make up most of a seed."""
    f, data = conn
    h = fields(data)
    if b"message_definition" in h:
        h[b"message_definition"] = b""
    return f, header(h)


def main():
    src, dst, per_conn, comp = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    buf = open(src, "rb").read()
    assert buf.startswith(MAGIC)
    top = list(records(buf, len(MAGIC), len(buf)))
    conns, msgs, seen = {}, [], {}
    for f, _, data in top:
        if f.get(b"op") == b"\x07":
            conns[f[b"conn"]] = (f, data)
        if f.get(b"op") != b"\x05":
            continue
        raw = data if f[b"compression"] == b"none" else bz2.decompress(data)
        for cf, _, cdata in records(raw, 0, len(raw)):
            if cf.get(b"op") == b"\x07":
                conns[cf[b"conn"]] = (cf, cdata)
            elif cf.get(b"op") == b"\x02" and seen.get(cf[b"conn"], 0) < per_conn:
                seen[cf[b"conn"]] = seen.get(cf[b"conn"], 0) + 1
                msgs.append((cf, cdata))
        if all(seen.get(c, 0) >= per_conn for c in conns):
            break
    conns = {c: slim(v) for c, v in conns.items()}
    inner = b"".join(record(f, d) for f, d in conns.values())
    offsets = {}
    for f, d in msgs:
        offsets.setdefault(f[b"conn"], []).append((f[b"time"], len(inner)))
        inner += record(f, d)
    stored = inner if comp == "none" else bz2.compress(inner)
    times = [f[b"time"] for f, _ in msgs]
    t_key = lambda t: struct.unpack("<II", t)[::-1]
    start, end = min(times, key=t_key), max(times, key=t_key)
    chunk = record({b"op": b"\x05", b"compression": comp.encode(),
                    b"size": struct.pack("<I", len(inner))}, stored)
    body = b""
    for c, lst in offsets.items():
        data = b"".join(t + struct.pack("<I", off) for t, off in lst)
        body += record({b"op": b"\x04", b"ver": struct.pack("<I", 1), b"conn": c,
                        b"count": struct.pack("<I", len(lst))}, data)
    head_len = 256  # real bags pad the header to 4096 bytes; the format allows any
    chunk_pos = len(MAGIC) + head_len
    index = b"".join(record(f, d) for f, d in conns.values())
    info_data = b"".join(c + struct.pack("<I", len(l)) for c, l in offsets.items())
    index += record({b"op": b"\x06", b"ver": struct.pack("<I", 1),
                     b"chunk_pos": struct.pack("<Q", chunk_pos), b"start_time": start,
                     b"end_time": end, b"count": struct.pack("<I", len(offsets))}, info_data)
    index_pos = chunk_pos + len(chunk) + len(body)
    bh = header({b"op": b"\x03", b"index_pos": struct.pack("<Q", index_pos),
                 b"conn_count": struct.pack("<I", len(conns)),
                 b"chunk_count": struct.pack("<I", 1)})
    pad = head_len - 8 - len(bh)
    bag_header = struct.pack("<I", len(bh)) + bh + struct.pack("<I", pad) + b" " * pad
    open(dst, "wb").write(MAGIC + bag_header + chunk + body + index)


main()
