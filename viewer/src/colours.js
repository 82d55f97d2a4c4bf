// Colours shared with dcseg's preview sheet (dcseg.io.exports.palette): golden-ratio hues.

export const SH_C0 = 0.28209479177387814;
export const NONE_RGB = [0.35, 0.35, 0.35];

function hsvToRgb(h, s, v) {
  const i = Math.floor(h * 6);
  const f = h * 6 - i;
  const p = v * (1 - s);
  const q = v * (1 - s * f);
  const t = v * (1 - s * (1 - f));
  return [[v, t, p], [q, v, p], [p, v, t], [p, q, v], [t, p, v], [v, p, q]][i % 6];
}

/** RGB in [0, 1] of palette entry `i` (instance id - 1, or class index). */
export function paletteRgb(i) {
  const [r, g, b] = hsvToRgb((i * 0.618034) % 1.0, 0.65, 0.95);
  return [Math.floor(r * 255) / 255, Math.floor(g * 255) / 255, Math.floor(b * 255) / 255];
}

export function cssColour(rgb) {
  const [r, g, b] = rgb.map((v) => Math.round(v * 255));
  return `rgb(${r}, ${g}, ${b})`;
}

export function sigmoid(x) {
  return 1 / (1 + Math.exp(-x));
}

export function clamp01(x) {
  return x < 0 ? 0 : x > 1 ? 1 : x;
}
