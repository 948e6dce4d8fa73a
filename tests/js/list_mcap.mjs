// Reads an MCAP file with the TypeScript @mcap/core reader (the one Foxglove's own MCAP
// support is built on) and prints, as JSON: the header profile, every channel with its schema
// name, schema encoding, message encoding and message count, and the first messages of each
// JSON channel, parsed. Used by tests/test_export_foxglove.py as an independent reader.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { decompress } from "fzstd";

const path = process.argv[2];
const limit = Number(process.argv[3] ?? "5");
const handle = await open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, size) => {
    const buffer = new Uint8Array(Number(size));
    await handle.read(buffer, 0, Number(size), Number(offset));
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: {
    zstd: (data, size) => decompress(data, new Uint8Array(Number(size))),
  },
});
const counts = new Map();
const first = {};
const decoder = new TextDecoder();
for await (const message of reader.readMessages()) {
  const channel = reader.channelsById.get(message.channelId);
  counts.set(channel.id, (counts.get(channel.id) ?? 0) + 1);
  if (channel.messageEncoding === "json") {
    const kept = (first[channel.topic] ??= []);
    if (kept.length < limit) kept.push(JSON.parse(decoder.decode(message.data)));
  }
}
const channels = [...reader.channelsById.values()].map((channel) => {
  const schema = reader.schemasById.get(channel.schemaId);
  return {
    topic: channel.topic,
    messageEncoding: channel.messageEncoding,
    schemaName: schema?.name ?? null,
    schemaEncoding: schema?.encoding ?? null,
    messages: counts.get(channel.id) ?? 0,
  };
});
console.log(JSON.stringify({ profile: reader.header.profile, channels, first }));
await handle.close();
