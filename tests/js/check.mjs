// The other side's readers of an rgtbus log (what Foxglove does): @mcap/core reads the file
// record by record, CRCs checked, its chunks decompressed by @mcap/support; every protobuf
// message is decoded by protobufjs from the FileDescriptorSet stored with its channel, every
// JSON one parsed. Prints one JSON line per message: {topic, log_time, value}; exits 1 on
// any error. Usage: node check.mjs LOG.mcap
import { readFile } from "node:fs/promises";

import { McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import protobufjs from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";

const data = await readFile(process.argv[2]);
const reader = new McapStreamReader({
  decompressHandlers: await loadDecompressHandlers(),
  validateCrcs: true,
});
reader.append(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));

const schemas = new Map();
const channels = new Map();
const types = new Map();
const out = [];
for (let record; (record = reader.nextRecord()); ) {
  if (record.type === "Schema") schemas.set(record.id, record);
  else if (record.type === "Channel") channels.set(record.id, record);
  else if (record.type === "Message") {
    const channel = channels.get(record.channelId);
    let value;
    if (channel.messageEncoding === "json") {
      value = JSON.parse(new TextDecoder().decode(record.data));
    } else if (channel.messageEncoding === "protobuf") {
      let type = types.get(channel.schemaId);
      if (type === undefined) {
        const schema = schemas.get(channel.schemaId);
        const set = descriptor.FileDescriptorSet.decode(schema.data);
        type = protobufjs.Root.fromDescriptor(set).lookupType(schema.name);
        types.set(channel.schemaId, type);
      }
      value = type.toObject(type.decode(record.data), { longs: Number, arrays: true });
    } else {
      throw new Error(`${channel.topic}: message encoding ${channel.messageEncoding}`);
    }
    out.push(JSON.stringify({ topic: channel.topic, log_time: Number(record.logTime), value }));
  }
}
if (!reader.done()) throw new Error("the file ends before its footer");
process.stdout.write(out.join("\n") + (out.length ? "\n" : ""));
