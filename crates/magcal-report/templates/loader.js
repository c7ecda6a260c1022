// Unpacks plotly.js from its block (zlib in base64, by the browser's DecompressionStream) and runs
// it; then draws each figure from its JSON block when it comes within a screen of the view (all of
// them where the browser cannot tell), so that the page shows at once however many views it holds.
// Figures wait in a queue, those on the screen ahead of those near it, and are drawn one per
// task, so that the browser paints each as it is done and a reader can scroll meanwhile.
(function () {
  function unpack() {
    var block = document.getElementById("magcal-plotly");
    if (!("DecompressionStream" in window)) {
      return Promise.reject(new Error("this browser cannot unpack the figures' plotly.js (DecompressionStream: Chrome 80, Firefox 113, Safari 16.4 or later)"));
    }
    var text = atob(block.textContent);
    var bytes = new Uint8Array(text.length);
    for (var i = 0; i < text.length; i++) { bytes[i] = text.charCodeAt(i); }
    var stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    // Indirect eval: plotly.js runs in the global scope, as its own script would.
    return new Response(stream).text().then(function (js) { (0, eval)(js); });
  }
  unpack().then(draw, function (e) {
    Array.prototype.forEach.call(document.querySelectorAll(".plotly-graph-div"), function (div) {
      div.textContent = "The figure cannot be drawn: " + e.message;
    });
    throw e;
  });

  function draw() {
    var queue = [], busy = false;
    function next() {
      var div = queue.shift();
      if (!div) { busy = false; return; }
      busy = true;
      var block = document.querySelector('script.magcal-figure[data-for="' + div.id + '"]');
      // The mark dates the drawing from the navigation (the browser tests' and benchmark's clock).
      Plotly.newPlot(div, JSON.parse(block.textContent)).then(function () {
        if (window.performance && performance.mark) { performance.mark("magcal-drawn " + div.id); }
      }).then(function () { setTimeout(next, 0); }, function () { setTimeout(next, 0); });
    }
    function want(div, first) {
      if (div.dataset.magcalDrawn) { return; }
      div.dataset.magcalDrawn = "1";
      if (first) { queue.unshift(div); } else { queue.push(div); }
      if (!busy) { busy = true; setTimeout(next, 0); }
    }
    var divs = Array.prototype.slice.call(document.querySelectorAll(".plotly-graph-div"));
    if (!("IntersectionObserver" in window)) { divs.forEach(function (d) { want(d, false); }); return; }
    var near = new IntersectionObserver(function (entries) {
      var seen = entries.filter(function (e) { return e.isIntersecting; });
      // Those near the view go in first, in the page's order; then those on it move ahead.
      seen.forEach(function (e) { near.unobserve(e.target); });
      seen.filter(function (e) { return !onScreen(e.target); }).forEach(function (e) { want(e.target, false); });
      seen.filter(function (e) { return onScreen(e.target); }).reverse().forEach(function (e) { want(e.target, true); });
    }, { rootMargin: "100% 0px" });
    function onScreen(div) {
      var r = div.getBoundingClientRect();
      return r.bottom > 0 && r.top < window.innerHeight;
    }
    divs.forEach(function (d) { near.observe(d); });
  }
})();
