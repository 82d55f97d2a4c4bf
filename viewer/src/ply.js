// Binary little-endian PLY: parse the vertex element (as dcseg writes it) and write subsets.

const TYPES = {
  char: [1, "getInt8"], int8: [1, "getInt8"],
  uchar: [1, "getUint8"], uint8: [1, "getUint8"],
  short: [2, "getInt16"], int16: [2, "getInt16"],
  ushort: [2, "getUint16"], uint16: [2, "getUint16"],
  int: [4, "getInt32"], int32: [4, "getInt32"],
  uint: [4, "getUint32"], uint32: [4, "getUint32"],
  float: [4, "getFloat32"], float32: [4, "getFloat32"],
  double: [8, "getFloat64"], float64: [8, "getFloat64"],
};

const END = "end_header\n";

/** Read the header and locate the vertex rows; throws an Error naming `name` and the fault. */
export function parsePly(buffer, name = "PLY") {
  const bytes = new Uint8Array(buffer);
  const head = new TextDecoder("latin1").decode(bytes.subarray(0, Math.min(bytes.length, 65536)));
  const end = head.indexOf(END);
  if (!head.startsWith("ply\n") || end < 0) throw new Error(`${name}: not a PLY file`);
  const lines = head.slice(0, end).split("\n").map((l) => l.trim()).filter(Boolean);
  const format = lines.find((l) => l.startsWith("format "));
  if (format !== "format binary_little_endian 1.0") {
    throw new Error(`${name}: only binary_little_endian PLY is supported (${format ?? "no format"})`);
  }
  const { count, props, stride } = vertexLayout(lines, name);
  const bodyOffset = end + END.length;
  if (bytes.length < bodyOffset + count * stride) {
    throw new Error(`${name}: truncated (${count} vertices of ${stride} bytes announced)`);
  }
  return { name, bytes, count, props, stride, bodyOffset, headerLines: lines };
}

function vertexLayout(lines, name) {
  let element = null;
  let seenVertex = false;
  let count = 0;
  let stride = 0;
  const props = new Map();
  for (const line of lines) {
    const words = line.split(/\s+/);
    if (words[0] === "element") {
      if (seenVertex && element === "vertex") break;
      element = words[1];
      if (element === "vertex") { seenVertex = true; count = Number(words[2]); }
      else if (!seenVertex) throw new Error(`${name}: element '${element}' before 'vertex'`);
    } else if (words[0] === "property" && element === "vertex") {
      if (words[1] === "list") throw new Error(`${name}: list property '${words[4]}' in vertex`);
      const type = TYPES[words[1]];
      if (!type) throw new Error(`${name}: unknown property type '${words[1]}'`);
      props.set(words[2], { offset: stride, size: type[0], getter: type[1] });
      stride += type[0];
    }
  }
  if (!seenVertex) throw new Error(`${name}: no 'vertex' element`);
  return { count, props, stride };
}

/** One vertex property as a Float32Array (floats) or Int32Array (integers). */
export function column(ply, prop, IntArray = Float32Array) {
  const p = ply.props.get(prop);
  if (!p) throw new Error(`${ply.name}: missing vertex property '${prop}'`);
  const out = new IntArray(ply.count);
  const view = new DataView(ply.bytes.buffer, ply.bytes.byteOffset + ply.bodyOffset);
  for (let i = 0, at = p.offset; i < ply.count; i++, at += ply.stride) {
    out[i] = view[p.getter](at, true);
  }
  return out;
}

export function hasProperty(ply, prop) {
  return ply.props.has(prop);
}

/** A PLY of the given vertex rows, byte for byte as in the source (same properties; other
 * elements are left out). */
export function subsetPly(ply, indices) {
  const header = [];
  let element = null;
  for (const line of ply.headerLines) {
    if (line.startsWith("element ")) element = line.split(/\s+/)[1];
    if (element === null) header.push(line);
    else if (element === "vertex") {
      header.push(line.startsWith("element vertex ") ? `element vertex ${indices.length}` : line);
    }
  }
  const text = new TextEncoder().encode(`${header.join("\n")}\n${END}`);
  const out = new Uint8Array(text.length + indices.length * ply.stride);
  out.set(text, 0);
  const body = ply.bytes.subarray(ply.bodyOffset);
  let at = text.length;
  for (const i of indices) {
    out.set(body.subarray(i * ply.stride, (i + 1) * ply.stride), at);
    at += ply.stride;
  }
  return out;
}
