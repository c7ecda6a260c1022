// Bundles index.js as plotly.js's own dist bundles are made (its tasks/util/bundle_wrapper.mjs):
// its esbuild configuration, its transform that strips the attributes' descriptions, minified,
// in the same UMD wrapper under the same licence header. One step more: plotly.js's WebGL modules
// come as one prebuilt webpack bundle (stackgl_modules/index.js) that exports those of every 3D
// trace type; the modules that only the types left out use (surface, cone, streamtube) are
// dropped from it, which esbuild cannot do inside a prebuilt bundle.
import fs from 'fs';
import { createRequire } from 'module';
import { build } from 'esbuild';
import browserifyAdapter from 'esbuild-plugin-browserify-adapter';

const require = createRequire(import.meta.url);
const config = require('plotly.js/esbuild-config.js');
const compressAttributes = require('plotly.js/tasks/compress_attributes.js');
const version = require('plotly.js/package.json').version;

// The exports of stackgl_modules/main.js that src/plots/gl3d, src/traces/scatter3d and
// src/traces/mesh3d require.
const STACKGL_KEPT = [
    'alpha_shape',
    'convex_hull',
    'delaunay_triangulate',
    'gl_error3d',
    'gl_line3d',
    'gl_mesh3d',
    'gl_plot3d',
    'gl_scatter3d',
];

// The webpack bundle `text` with its entry module exporting only `kept`, and without the modules
// no longer reachable from it. Its modules are `\n/***/ ID:\n` headers followed by their
// function, the entry first, and require one another as `__webpack_require__(ID)`.
function pruneStackgl(text, kept) {
    const starts = [...text.matchAll(/\n\/\*\*\*\/ (\d+):\n/g)];
    const end = text.indexOf('\n/******/ \t});');
    if (starts.length === 0 || end < 0) throw new Error('stackgl_modules/index.js: not the webpack bundle expected');
    const modules = new Map();
    starts.forEach((m, k) => {
        const to = k + 1 < starts.length ? starts[k + 1].index : end;
        modules.set(m[1], text.slice(m.index, to));
    });
    const entry = starts[0][1];
    const exported = /^\s+(\w+): __webpack_require__\(\d+\),?$/;
    const lines = modules.get(entry).split('\n');
    const names = lines.map((l) => l.match(exported)).filter(Boolean).map((m) => m[1]);
    for (const name of kept) {
        if (!names.includes(name)) throw new Error(`stackgl_modules/index.js exports no ${name}`);
    }
    modules.set(entry, lines.filter((l) => !exported.test(l) || kept.includes(l.match(exported)[1])).join('\n'));
    const reached = new Set([entry]);
    const todo = [entry];
    while (todo.length > 0) {
        for (const m of modules.get(todo.pop()).matchAll(/__webpack_require__\((\d+)\)/g)) {
            if (!reached.has(m[1])) {
                reached.add(m[1]);
                todo.push(m[1]);
            }
        }
    }
    const body = starts.map((m) => m[1]).filter((id) => reached.has(id)).map((id) => modules.get(id));
    return text.slice(0, starts[0].index) + body.join('') + text.slice(end);
}

const stackgl = {
    name: 'stackgl-prune',
    setup(b) {
        b.onLoad({ filter: /plotly\.js[\\/]stackgl_modules[\\/]index\.js$/ }, (args) => ({
            contents: pruneStackgl(fs.readFileSync(args.path, 'utf8'), STACKGL_KEPT),
            loader: 'js',
        }));
    },
};

const out = process.argv[2];
await build({
    ...config,
    entryPoints: ['index.js'],
    outfile: out,
    minify: true,
    logLevel: 'warning',
    plugins: [stackgl].concat(config.plugins, [browserifyAdapter(compressAttributes)]),
});
const css = out.replace(/\.js$/, '.css');
if (fs.existsSync(css)) fs.unlinkSync(css);

const header = [
    '/**',
    `* plotly.js v${version} (magcal: bar, box, heatmap, mesh3d, scatter, scatter3d - minified)`,
    '* Copyright 2012-2025, Plotly, Inc.',
    '* All rights reserved.',
    '* Licensed under the MIT license',
    '*/',
].join('\n');
const wrapped = [
    header,
    '(',
    ' function(root, factory) {',
    '  if (typeof module === "object" && module.exports) {',
    '   module.exports = factory();',
    '  } else {',
    '   root.moduleName = factory();',
    '  }',
    '} (typeof self !== "undefined" ? self : this, () => {',
    fs.readFileSync(out, 'utf8').trimEnd(),
    'window.Plotly = Plotly;',
    'return Plotly;',
    '}));',
    '',
].join('\n');
fs.writeFileSync(out, wrapped);
