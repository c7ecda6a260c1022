// plotly.js's core (which holds the scatter trace) and the trace types magcal's report pages draw;
// the tests check every `type` of a page's figures against what this registers.
'use strict';

var Plotly = require('plotly.js/lib/core');

Plotly.register([
    require('plotly.js/lib/bar'),
    require('plotly.js/lib/box'),
    require('plotly.js/lib/heatmap'),
    require('plotly.js/lib/mesh3d'),
    require('plotly.js/lib/scatter3d'),
]);

module.exports = Plotly;
