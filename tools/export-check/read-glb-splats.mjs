// Read a GLB's KHR_gaussian_splatting primitives with the PlayCanvas engine's own glTF parser
// (GlbParser and its khr-gaussian-splatting extension, on a null graphics device: no GPU).
// Prints a JSON list, one entry per file: its nodes as the engine made them, each with the
// Gaussians of its mesh as the engine decoded them (columns named as PlayCanvas names them:
// x y z, rot_0..3 = w x y z, scale_*, opacity, f_dc_*, f_rest_*; the engine reorders the
// Gaussians in Morton order). Usage: node read-glb-splats.mjs FILE...
import { readFile } from "node:fs/promises";

const src = (path) => new URL(`./node_modules/playcanvas/build/playcanvas/src/${path}`, import.meta.url);
const { GlbParser } = await import(src("framework/parsers/glb-parser.js"));
const { khrGaussianSplatting } = await import(src("framework/parsers/glb/extensions/khr-gaussian-splatting.js"));
const { NullGraphicsDevice } = await import(src("platform/graphics/null/null-graphics-device.js"));

const device = new NullGraphicsDevice();
const registry = { loader: { _app: null } }; // no images to load: nothing else is asked of it

function parse(path, bytes) {
  const data = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
  return new Promise((resolve, reject) => {
    GlbParser.parse(path, "", data, device, registry, {}, [khrGaussianSplatting], (error, result) =>
      error ? reject(new Error(`${path}: ${error}`)) : resolve(result),
    );
  });
}

function columns(resource) {
  const data = resource.gsplatData;
  const names = data.getElement("vertex").properties.map((p) => p.name);
  return {
    count: data.numSplats,
    activated: data.activated === true, // linear scale and opacity, as the extension stores them
    columns: Object.fromEntries(names.map((name) => [name, Array.from(data.getProp(name))])),
  };
}

const files = [];
for (const path of process.argv.slice(2)) {
  const result = await parse(path, await readFile(path));
  const nodes = result.nodes.map((node, i) => {
    const mesh = result.gltf.nodes[i].mesh ?? null;
    const splats = mesh === null ? [] : (result.gsplats[mesh] ?? []).map(columns);
    return { name: node.name, mesh, splats };
  });
  files.push({ file: path, nodes });
}
process.stdout.write(JSON.stringify(files));
