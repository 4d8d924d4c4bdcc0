// Independent check of an adfusion MCAP file with the TypeScript reader (@mcap/core).
// usage: node read_mcap.cjs NODE_MODULES_PARENT FILE.mcap
// Prints JSON: header, channels with their schemas, message counts per topic, the text of every
// JSON-encoded message, metadata and attachment names.
"use strict";
const fs = require("node:fs");
const path = require("node:path");
const { createRequire } = require("node:module");

async function main() {
  const [modulesParent, file] = process.argv.slice(2);
  const req = createRequire(path.join(path.resolve(modulesParent), "package.json"));
  const { McapIndexedReader } = req("@mcap/core");
  const fzstd = req("fzstd");
  const lz4 = req("lz4js");

  const handle = await fs.promises.open(file, "r");
  const size = (await handle.stat()).size;
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      await handle.read(buf, 0, Number(length), Number(offset));
      return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
    },
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: {
      zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))),
      lz4: (data, size) => lz4.decompress(data, Number(size)),
    },
  });
  const text = new TextDecoder("utf-8", { fatal: true });
  const channels = [];
  for (const ch of reader.channelsById.values()) {
    const schema = reader.schemasById.get(ch.schemaId);
    const isJson = schema && schema.encoding === "jsonschema";
    channels.push({
      id: ch.id,
      topic: ch.topic,
      messageEncoding: ch.messageEncoding,
      schemaName: schema ? schema.name : "",
      schemaEncoding: schema ? schema.encoding : "",
      schemaData: schema
        ? isJson ? text.decode(schema.data) : Buffer.from(schema.data).toString("base64")
        : "",
    });
  }
  const counts = {};
  const jsonMessages = {};
  const byId = reader.channelsById;
  let previous = -1n;
  let ordered = true;
  for await (const msg of reader.readMessages({ validateCrcs: true })) {
    const ch = byId.get(msg.channelId);
    counts[ch.topic] = (counts[ch.topic] || 0) + 1;
    if (msg.logTime < previous) ordered = false;
    previous = msg.logTime;
    if (ch.messageEncoding === "json") {
      (jsonMessages[ch.topic] = jsonMessages[ch.topic] || []).push(text.decode(msg.data));
    }
  }
  const metadata = [];
  for await (const m of reader.readMetadata()) {
    metadata.push({ name: m.name, metadata: Object.fromEntries(m.metadata) });
  }
  const attachments = [];
  for await (const a of reader.readAttachments({ validateCrcs: true })) {
    attachments.push({ name: a.name, mediaType: a.mediaType, size: a.data.byteLength });
  }
  await handle.close();
  process.stdout.write(JSON.stringify({
    header: reader.header,
    statisticsMessageCount: reader.statistics ? Number(reader.statistics.messageCount) : null,
    channels, counts, ordered, jsonMessages, metadata, attachments,
  }));
}

main().catch((err) => {
  process.stderr.write(String(err && err.stack ? err.stack : err) + "\n");
  process.exit(1);
});
