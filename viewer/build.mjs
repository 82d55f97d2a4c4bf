// Bundle src/ into dcseg/viewer/static/viewer.js (served by `dcseg view` and the API).
import { build } from "esbuild";

await build({
  entryPoints: ["src/main.js"],
  bundle: true,
  format: "esm",
  minify: true,
  target: "es2022",
  legalComments: "eof",
  outfile: "../dcseg/viewer/static/viewer.js",
  logLevel: "warning",
});
