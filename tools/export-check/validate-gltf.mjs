// Validate glTF / GLB files with the Khronos glTF validator; prints one JSON report per file
// (a JSON list). Usage: node validate-gltf.mjs FILE...
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";

const validator = createRequire(import.meta.url)("gltf-validator");
const reports = [];
for (const path of process.argv.slice(2)) {
  const bytes = new Uint8Array(await readFile(path));
  reports.push(await validator.validateBytes(bytes, { uri: path, maxIssues: 200 }));
}
process.stdout.write(JSON.stringify(reports));
