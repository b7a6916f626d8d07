"""Reads an exported MCAP with Python's `mcap` reader and `mcap-protobuf-support`, as Foxglove's own tools do,
and prints what it decoded as one JSON object (tests/tests/export.rs compares it with the flight log).

Usage: python read_mcap.py FILE.mcap

Every message is decoded: protobuf channels through the schemas' FileDescriptorSets (mcap_protobuf's
DecoderFactory), JSON channels with json.loads. A message that does not decode is an error (exit 1).
"""

import hashlib
import json
import sys

from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory


class JsonDecoderFactory(McapDecoderFactory):
    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json":
            return lambda data: json.loads(data)
        return None


def xyzw(v):
    return [v.x, v.y, v.z, v.w]


def main(path):
    out = {
        "channels": {},
        "estimate_poses": [],
        "forward_images": [],
        "forward_annotations_first": None,  # the first that is not empty
        "tf_last": {},
        "scene_last": [],
        "profile": None,
        "metadata": {},
    }
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufDecoderFactory(), JsonDecoderFactory()])
        out["profile"] = reader.get_header().profile
        for m in reader.iter_metadata():
            out["metadata"][m.name] = sorted(m.metadata.keys())
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            c = out["channels"].setdefault(
                channel.topic,
                {
                    "message_encoding": channel.message_encoding,
                    "schema_name": schema.name if schema else "",
                    "schema_encoding": schema.encoding if schema else "",
                    "count": 0,
                },
            )
            c["count"] += 1
            topic = channel.topic
            if topic == "/estimate/pose":
                p = decoded.pose
                out["estimate_poses"].append(
                    [message.log_time, p.position.x, p.position.y, p.position.z] + xyzw(p.orientation)
                )
            elif topic == "/camera/forward/image":
                out["forward_images"].append(
                    [message.log_time, decoded.format, hashlib.sha256(decoded.data).hexdigest()]
                )
            elif topic == "/camera/forward/annotations":
                if out["forward_annotations_first"] is None and len(decoded.points) > 0:
                    out["forward_annotations_first"] = {
                        "index": c["count"] - 1,
                        "points": [
                            {"type": a.type, "points": [[q.x, q.y] for q in a.points]} for a in decoded.points
                        ],
                    }
            elif topic == "/tf":
                for t in decoded.transforms:
                    tr = t.translation
                    out["tf_last"][t.child_frame_id] = [t.parent_frame_id, tr.x, tr.y, tr.z] + xyzw(t.rotation)
            elif topic == "/scene":
                out["scene_last"] = [e.id for e in decoded.entities]
            elif channel.message_encoding == "json":
                if not isinstance(decoded, dict) or "t_s" not in decoded:
                    raise SystemExit(f"{topic}: a JSON message without t_s at {message.log_time}")
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
