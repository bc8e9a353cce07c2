#!/usr/bin/env python3
"""Independent check of an amstack MCAP file, with the PyPI `mcap` package (not our code).

Usage: mcap_check.py FILE [--expect TOPIC=COUNT ...] [--require-complete] [--json]

Reads the file front to back with mcap's streaming (non-seeking) record reader, so a file cut
short by a crash is read up to its last complete chunk. Prints the header, the metadata
records, every channel with its schema name, encodings and message count, and checks:

  - every message of a `json` channel is valid JSON, and every `jsonschema` schema is JSON;
  - every payload conforms to its channel's schema (a subset of JSON Schema: type, properties,
    required, additionalProperties=false, items, min/maxItems, minimum/maximum, enum, const,
    anyOf/oneOf) -- so NaN logged as null in a number field is caught;
  - for a complete file, the summary's statistics agree with the messages streamed;
  - each --expect TOPIC=COUNT (a topic absent from the file counts 0);
  - with --require-complete, that the file ends with its footer (a finished run);
  - every foxglove.CompressedImage decodes (protobuf, the Foxglove SDK's; or, in logs of format
    version 1, JSON with base64 data), then PNG (signature, IHDR, CRCs, the
    inflated IDAT holding exactly height rows of width pixels) or JPEG (SOI/EOI markers); its
    size and a SHA-256 of its bytes per message are reported under "images" (by topic), and a
    PNG's size must match the width/height of the camera's foxglove.CameraCalibration;
  - every message of a `protobuf` channel (the Foxglove SDK's well-known schemas: the 3D scene)
    decodes with the message class built from its schema record (a FileDescriptorSet), by
    Google's `protobuf` package; "decoded" reports per topic the type, the count, and what the
    messages hold (FrameTransforms: the frames; SceneUpdate: the entity ids and primitives).

Exit status: 0 when every check passes, 1 when one fails or the file is not MCAP, 2 on bad
usage. --json prints one JSON object instead of text (same content). Run it with the venv that
scripts/setup-python.sh creates:  "$(scripts/setup-python.sh)" scripts/mcap_check.py run.mcap
"""

import argparse
import base64
import hashlib
import json
import struct
import sys
import zlib

try:
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema, Statistics
    from mcap.stream_reader import StreamReader
except ImportError:  # pragma: no cover - environment problem, not a check failure
    print("mcap_check: the Python 'mcap' package is missing: run scripts/setup-python.sh "
          "and use the python it prints", file=sys.stderr)
    sys.exit(2)

MAX_ERRORS_SHOWN = 20


def protobuf_message_class(name, descriptor_set):
    """The message class `name` of a serialized protobuf FileDescriptorSet (as an MCAP schema
    record or a Foxglove WebSocket `advertise` carries it)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def protobuf_class(schema):
    """The message class of a protobuf schema record."""
    return protobuf_message_class(schema.name, schema.data)


def summarise_protobuf(entry, message):
    """Adds what a decoded Foxglove message holds to its topic's entry."""
    name = message.DESCRIPTOR.full_name
    if name == "foxglove.FrameTransforms":
        for t in message.transforms:
            pair = f"{t.parent_frame_id}->{t.child_frame_id}"
            if pair not in entry.setdefault("frames", []):
                entry["frames"].append(pair)
    elif name == "foxglove.SceneUpdate":
        prims = entry.setdefault("primitives", {})
        for e in message.entities:
            if e.id not in entry.setdefault("entities", []):
                entry["entities"].append(e.id)
            for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts"):
                n = len(getattr(e, kind))
                if n:
                    prims[kind] = prims.get(kind, 0) + n

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Bytes per pixel of 8-bit PNG colour types: grey, RGB, palette, grey+alpha, RGBA.
PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def decode_png(data):
    """(width, height) of a PNG whose chunks and pixel data are whole; raises ValueError."""
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError("no PNG signature")
    at, width, height, channels, idat = 8, None, None, None, b""
    while at < len(data):
        if at + 8 > len(data):
            raise ValueError("truncated chunk header")
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        body = data[at + 8:at + 8 + length]
        crc = data[at + 8 + length:at + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise ValueError(f"truncated {kind!r} chunk")
        if zlib.crc32(kind + body) != struct.unpack(">I", crc)[0]:
            raise ValueError(f"bad CRC in {kind!r} chunk")
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            if depth != 8 or colour not in PNG_CHANNELS:
                raise ValueError(f"unexpected bit depth {depth} / colour type {colour}")
            channels = PNG_CHANNELS[colour]
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
        at += 12 + length
    if width is None:
        raise ValueError("no IHDR chunk")
    raw = zlib.decompress(idat)
    if len(raw) != height * (1 + width * channels):
        raise ValueError(f"pixel data of {len(raw)} bytes for {width}x{height}")
    return width, height


def check_image(payload):
    """(format, width or None, height or None, sha256) of a foxglove.CompressedImage in JSON
    (log format version 1: the bytes in base64)."""
    data = base64.b64decode(payload.get("data", ""), validate=True)
    return check_image_bytes(data, payload.get("format"))


def check_image_bytes(data, fmt):
    """(format, width or None, height or None, sha256) of an image's bytes in `fmt`."""
    digest = hashlib.sha256(data).hexdigest()
    if fmt == "png":
        w, h = decode_png(data)
        return fmt, w, h, digest
    if fmt == "jpeg":
        if not (data.startswith(b"\xff\xd8") and data.endswith(b"\xff\xd9")):
            raise ValueError("not a JPEG (SOI/EOI markers missing)")
        return fmt, None, None, digest
    raise ValueError(f"unknown image format {fmt!r}")


def type_ok(value, typ):
    if typ == "null":
        return value is None
    if typ == "boolean":
        return isinstance(value, bool)
    if typ == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if typ == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if typ == "string":
        return isinstance(value, str)
    if typ == "array":
        return isinstance(value, list)
    if typ == "object":
        return isinstance(value, dict)
    return True  # unknown type keyword: not ours to judge


def validate(value, schema, path="$"):
    """Yields one message per violation of the supported JSON Schema subset."""
    if schema is True or not isinstance(schema, dict):
        return
    if schema is False:
        yield f"{path}: schema allows nothing"
        return
    typ = schema.get("type")
    if typ is not None:
        types = typ if isinstance(typ, list) else [typ]
        if not any(type_ok(value, t) for t in types):
            yield f"{path}: {json.dumps(value)[:60]} is not {' or '.join(types)}"
            return
    if "const" in schema and value != schema["const"]:
        yield f"{path}: {json.dumps(value)[:60]} is not the constant {json.dumps(schema['const'])}"
    if "enum" in schema and value not in schema["enum"]:
        yield f"{path}: {json.dumps(value)[:60]} is not one of {json.dumps(schema['enum'])[:60]}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            yield f"{path}: {value} < minimum {schema['minimum']}"
        if "maximum" in schema and value > schema["maximum"]:
            yield f"{path}: {value} > maximum {schema['maximum']}"
    if isinstance(value, dict):
        props = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in value:
                yield f"{path}: required property '{key}' missing"
        for key, sub in value.items():
            if key in props:
                yield from validate(sub, props[key], f"{path}.{key}")
            elif schema.get("additionalProperties") is False:
                yield f"{path}: unexpected property '{key}'"
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            yield f"{path}: {len(value)} items < minItems {schema['minItems']}"
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            yield f"{path}: {len(value)} items > maxItems {schema['maxItems']}"
        items = schema.get("items")
        if isinstance(items, dict):
            for i, sub in enumerate(value):
                yield from validate(sub, items, f"{path}[{i}]")
    for key, need in (("anyOf", "any"), ("oneOf", "one")):
        if key in schema:
            matches = sum(1 for s in schema[key] if not any(True for _ in validate(value, s, path)))
            if (need == "any" and matches == 0) or (need == "one" and matches != 1):
                yield f"{path}: matches {matches} of the {key} alternatives"


def parse_expectations(items):
    expected = {}
    for item in items:
        topic, sep, count = item.rpartition("=")
        if not sep or not topic or not count.isdigit():
            raise ValueError(f"--expect wants TOPIC=COUNT, got '{item}'")
        expected[topic] = int(count)
    return expected


def check(path, expected, require_complete):
    report = {
        "file": path,
        "header": None,
        "complete": False,
        "stopped_by": None,
        "metadata": [],
        "channels": [],
        "message_count": 0,
        "summary_statistics": None,
        "images": {},
        "decoded": {},
        "errors": [],
    }
    protobuf_classes = {}
    errors = report["errors"]
    schemas, channels, counts = {}, {}, {}
    parsed_schemas = {}
    calibrations = {}
    stats = None

    def note_image(topic, sequence, check):
        entry = report["images"].setdefault(topic, {
            "count": 0, "format": None, "width": None, "height": None, "sha256": []})
        try:
            fmt, w, h, digest = check()
        except (ValueError, TypeError, zlib.error) as e:
            errors.append(f"{topic} #{sequence}: image: {e}")
            return
        entry["count"] += 1
        entry["format"], entry["width"], entry["height"] = fmt, w, h
        entry["sha256"].append(digest)

    try:
        with open(path, "rb") as f:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Header):
                    report["header"] = {"profile": record.profile, "library": record.library}
                elif isinstance(record, Schema):
                    schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    channels.setdefault(record.id, record)
                    counts.setdefault(record.id, 0)
                elif isinstance(record, Metadata):
                    report["metadata"].append({"name": record.name, "metadata": dict(record.metadata)})
                elif isinstance(record, Statistics):
                    stats = record
                elif isinstance(record, Footer):
                    report["complete"] = True
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None:
                        errors.append(f"message on unknown channel {record.channel_id}")
                        continue
                    counts[record.channel_id] += 1
                    report["message_count"] += 1
                    if channel.message_encoding == "protobuf":
                        s = schemas.get(channel.schema_id)
                        if s is None or s.encoding != "protobuf":
                            errors.append(f"{channel.topic}: protobuf messages without a protobuf schema")
                            continue
                        cls = protobuf_classes.get(channel.schema_id)
                        if cls is None:
                            try:
                                cls = protobuf_class(s)
                            except Exception as e:  # a schema the protobuf package refuses
                                errors.append(f"schema {s.name}: not a usable FileDescriptorSet: {e}")
                                cls = False
                            protobuf_classes[channel.schema_id] = cls
                        if not cls:
                            continue
                        try:
                            message = cls.FromString(record.data)
                        except Exception as e:
                            errors.append(f"{channel.topic} #{record.sequence}: does not decode as {s.name}: {e}")
                            continue
                        entry = report["decoded"].setdefault(channel.topic, {"type": s.name, "count": 0})
                        entry["count"] += 1
                        summarise_protobuf(entry, message)
                        if s.name == "foxglove.CompressedImage":
                            note_image(channel.topic, record.sequence,
                                       lambda m=message: check_image_bytes(bytes(m.data), m.format))
                        elif s.name == "foxglove.CameraCalibration":
                            calibrations[channel.topic] = (message.width, message.height)
                        continue
                    if channel.message_encoding != "json":
                        continue
                    try:
                        payload = json.loads(record.data)
                    except ValueError as e:
                        errors.append(f"{channel.topic} #{record.sequence}: not JSON: {e}")
                        continue
                    schema = parsed_schemas.get(channel.schema_id)
                    if schema is None and channel.schema_id in schemas:
                        s = schemas[channel.schema_id]
                        if s.encoding == "jsonschema":
                            try:
                                schema = json.loads(s.data)
                            except ValueError as e:
                                errors.append(f"schema {s.name}: not JSON: {e}")
                                schema = True
                        else:
                            schema = True
                        parsed_schemas[channel.schema_id] = schema
                    for problem in validate(payload, schema if schema is not None else True):
                        errors.append(f"{channel.topic} #{record.sequence}: {problem}")
                    name = schemas[channel.schema_id].name if channel.schema_id in schemas else None
                    if name == "foxglove.CompressedImage":
                        note_image(channel.topic, record.sequence,
                                   lambda p=payload: check_image(p))
                    elif name == "foxglove.CameraCalibration":
                        calibrations[channel.topic] = (payload.get("width"), payload.get("height"))
    except OSError as e:
        errors.append(f"cannot read {path}: {e}")
        return report
    except Exception as e:  # the streaming reader's ways of meeting a cut-short file
        report["stopped_by"] = f"{type(e).__name__}: {e}".rstrip(": ")
        report["complete"] = False
    if report["header"] is None:
        errors.append(f"{path} is not an MCAP file ({report['stopped_by']})")
        return report

    for cid, channel in sorted(channels.items()):
        schema = schemas.get(channel.schema_id)
        report["channels"].append({
            "topic": channel.topic,
            "schema_name": schema.name if schema else None,
            "schema_encoding": schema.encoding if schema else None,
            "message_encoding": channel.message_encoding,
            "count": counts[cid],
        })
    if stats is not None:
        report["summary_statistics"] = {
            "message_count": stats.message_count,
            "chunk_count": stats.chunk_count,
            "channel_count": stats.channel_count,
            "schema_count": stats.schema_count,
            "metadata_count": stats.metadata_count,
            "message_start_time": stats.message_start_time,
            "message_end_time": stats.message_end_time,
        }
        if report["complete"]:
            for cid, n in stats.channel_message_counts.items():
                if counts.get(cid, 0) != n:
                    topic = channels[cid].topic if cid in channels else f"channel {cid}"
                    errors.append(f"{topic}: summary says {n} messages, stream has {counts.get(cid, 0)}")
    by_topic = {}
    for c in report["channels"]:
        by_topic[c["topic"]] = by_topic.get(c["topic"], 0) + c["count"]
    for topic, want in sorted(expected.items()):
        got = by_topic.get(topic, 0)
        if got != want:
            errors.append(f"expected {want} messages on {topic}, found {got}")
    for topic, entry in sorted(report["images"].items()):
        calibration = topic[: -len("/image")] + "/calibration" if topic.endswith("/image") else None
        size = calibrations.get(calibration)
        if size is not None and entry["width"] is not None and size != (entry["width"], entry["height"]):
            errors.append(f"{topic}: {entry['width']}x{entry['height']} images, "
                          f"calibration says {size[0]}x{size[1]}")
    if require_complete and not report["complete"]:
        errors.append(f"file is not complete (no footer): {report['stopped_by']}")
    return report


def print_text(report):
    p = print
    p(f"file: {report['file']}")
    if report["header"]:
        p(f"library: {report['header']['library']}  profile: '{report['header']['profile']}'")
    if report["complete"]:
        p("complete: yes (footer read)")
    elif report["header"]:
        p(f"complete: no (stream ended: {report['stopped_by']})")
    for m in report["metadata"]:
        p(f"metadata {m['name']}:")
        for k, v in sorted(m["metadata"].items()):
            p(f"  {k}: {v}")
    p(f"channels: {len(report['channels'])}")
    width = max([len(c["topic"]) for c in report["channels"]] + [5])
    for c in report["channels"]:
        p(f"  {c['topic']:<{width}}  {c['schema_name']} ({c['schema_encoding']}, {c['message_encoding']})"
          f"  {c['count']} messages")
    for topic, d in sorted(report["decoded"].items()):
        what = ", ".join(f"{k} {len(v) if isinstance(v, list) else v}" for k, v in d.items()
                         if k not in ("type", "count"))
        p(f"  decoded {topic}: {d['count']} x {d['type']}" + (f" ({what})" if what else ""))
    p(f"messages: {report['message_count']}")
    for topic, entry in sorted(report["images"].items()):
        p(f"  {topic}: {entry['count']} {entry['format']} images, {entry['width']}x{entry['height']}")
    if report["summary_statistics"]:
        s = report["summary_statistics"]
        p(f"summary: {s['message_count']} messages in {s['chunk_count']} chunks, "
          f"log time {s['message_start_time']}..{s['message_end_time']} ns")
    if report["errors"]:
        p(f"FAILED: {len(report['errors'])} problem(s)")
        for e in report["errors"][:MAX_ERRORS_SHOWN]:
            p(f"  {e}")
        if len(report["errors"]) > MAX_ERRORS_SHOWN:
            p(f"  ... and {len(report['errors']) - MAX_ERRORS_SHOWN} more")
    else:
        p("ok: every message is JSON and matches its schema; expectations met")


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("file")
    parser.add_argument("--expect", action="append", default=[], metavar="TOPIC=COUNT",
                        help="require exactly COUNT messages on TOPIC (repeatable)")
    parser.add_argument("--require-complete", action="store_true",
                        help="fail when the file has no footer (the run did not finish)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    try:
        expected = parse_expectations(args.expect)
    except ValueError as e:
        parser.error(str(e))
    report = check(args.file, expected, args.require_complete)
    if args.json:
        json.dump(report, sys.stdout, indent=2, sort_keys=True)
        print()
    else:
        print_text(report)
    return 1 if report["errors"] else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
