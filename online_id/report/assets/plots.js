// Draws every figure of the page from its plotly.js specification (a script.plot-spec beside its div).
// When all are drawn, <body data-plots-drawn="N"> says how many (the browser tests wait for it).
(function () {
  "use strict";
  // no logo, no link to an online editor (the page works offline), resizes with the window
  var CONFIG = {displaylogo: false, responsive: true, showLink: false, showSendToCloud: false};
  window.onlineId = {config: CONFIG};
  var specs = document.querySelectorAll("script.plot-spec");
  var pending = [];
  specs.forEach(function (s) {
    var spec = JSON.parse(s.textContent);
    pending.push(Plotly.newPlot(s.dataset.for, spec.data, spec.layout, CONFIG));
  });
  Promise.all(pending).then(function () {
    document.body.dataset.plotsDrawn = String(pending.length);
  });
})();
