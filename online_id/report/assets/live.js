// The live page of `online-id listen --web`: polls /snapshot.json and redraws (window.LIVE: settings).
(function () {
  "use strict";
  var cfg = window.LIVE, updates = 0, drawn = false, lastVersion = null;
  function fmt(v, digits) {
    if (v === null || v === undefined || !isFinite(v)) { return "—"; }
    var x = Number(Number(v).toPrecision(digits));
    // as the report's tables: whole numbers from 10,000 with thousands separators, no "1.1196e+5"
    if (Math.abs(x) >= 1e4 && Math.abs(x) < 1e9) { return Math.round(x).toLocaleString("en-US"); }
    return String(x);
  }
  function set(id, text) { document.getElementById(id).textContent = text; }
  function rgba(hex, a) {
    var h = hex.replace("#", "");
    return "rgba(" + parseInt(h.substr(0, 2), 16) + "," + parseInt(h.substr(2, 2), 16) + "," +
      parseInt(h.substr(4, 2), 16) + "," + a + ")";
  }
  function trajectories(s) {
    var data = [], layout = {height: 780, showlegend: false, hovermode: "x unified",
      margin: {l: 70, r: 20, t: 20, b: 40}, font: {size: 12},
      grid: {rows: 4, columns: 2, pattern: "independent"}};
    var h = s.history, t = h.time;
    s.parameters.forEach(function (n, i) {
      var ax = i === 0 ? "" : String(i + 1), v = h.values[i], sd = h.std[i];
      var hi = v.map(function (x, k) { return x === null || sd[k] === null ? null : x + sd[k]; });
      var lo = v.map(function (x, k) { return x === null || sd[k] === null ? null : x - sd[k]; });
      var c = cfg.colours[i];
      data.push({type: "scatter", mode: "lines", x: t, y: hi, line: {width: 0}, hoverinfo: "skip",
                 xaxis: "x" + ax, yaxis: "y" + ax});
      data.push({type: "scatter", mode: "lines", x: t, y: lo, line: {width: 0}, fill: "tonexty",
                 fillcolor: rgba(c, 0.22), hoverinfo: "skip", xaxis: "x" + ax, yaxis: "y" + ax});
      data.push({type: "scatter", mode: "lines", x: t, y: v, name: n, line: {width: 1.6, color: c},
                 xaxis: "x" + ax, yaxis: "y" + ax});
      // as the report: the first 10 % of the run (the prior's wide band) is left out of the range
      var from = t[0] + 0.1 * (t[t.length - 1] - t[0]), y0 = Infinity, y1 = -Infinity;
      t.forEach(function (tk, k) {
        if (tk >= from && lo[k] !== null && hi[k] !== null) { y0 = Math.min(y0, lo[k]); y1 = Math.max(y1, hi[k]); }
      });
      var axis = {title: {text: n + " [" + cfg.units[n] + "]", font: {size: 11}}};
      if (isFinite(y0) && isFinite(y1) && y1 > y0) {
        var pad = 0.08 * (y1 - y0);
        axis.range = [y0 - pad, y1 + pad];
      }
      layout["yaxis" + ax] = axis;
    });
    return [data, layout];
  }
  function meter(s) {
    var m = s.meter;
    // as the report's meter: colours logarithmic in the share, from 0.05 % (white) to 100 %
    var z = m.share.map(function (row) {
      return row.map(function (v) { return Math.log10(Math.max(v === null ? 0 : v, 0.05)); });
    });
    var data = [{type: "heatmap", x: m.middle, y: s.parameters, z: z, customdata: m.share,
      zmin: Math.log10(0.05), zmax: 2,
      colorscale: [[0, "#ffffff"], [0.15, "#deebf7"], [0.5, "#6baed6"], [0.8, "#2171b5"], [1, "#08306b"]],
      colorbar: {title: {text: "%"}, tickvals: [-1, 0, 1, 2], ticktext: ["0.1", "1", "10", "100"]},
      hovertemplate: "%{y}: %{customdata:.2f} % of what the filter learned (fall of log σ), window at %{x:.1f} s" +
        "<extra></extra>"}];
    var layout = {height: 300, margin: {l: 70, r: 20, t: 10, b: 40}, font: {size: 12},
      xaxis: {title: {text: "stream time [s]"}}, yaxis: {autorange: "reversed"}};
    return [data, layout];
  }
  function apply(s) {
    updates += 1;
    set("updates", String(updates));
    var status = s.running ? "running" : "ended: " + (s.ended_by || "");
    set("status", status + (s.time !== null ? " · stream time " + fmt(s.time, 6) + " s" : ""));
    document.getElementById("status").dataset.running = String(s.running);
    set("time", s.time === null ? "—" : Number(s.time).toFixed(2) + " s");
    var samples = document.getElementById("samples");
    samples.textContent = String(s.samples);
    samples.dataset.value = String(s.samples);
    set("speed", s.speed === undefined ? "—" : (3.6 * s.speed).toFixed(1) + " km/h");
    var v = document.getElementById("verdict");
    v.textContent = s.verdict;
    v.className = "verdict " + (s.consistent === null || s.judged === false ? "neutral" : s.consistent ? "good" : "bad");
    if (s.values) {
      s.parameters.forEach(function (n, i) {
        var val = document.querySelector('td.value[data-param="' + n + '"]');
        val.textContent = fmt(s.values[i], 6);
        val.dataset.value = String(s.values[i]);
        var sd = document.querySelector('td.std[data-param="' + n + '"]');
        sd.textContent = fmt(s.std[i], 3);
        sd.dataset.value = String(s.std[i]);
        document.querySelector('td.rel[data-param="' + n + '"]').textContent = fmt(100 * s.std[i] / s.values[i], 3);
      });
    }
    var loss = s.loss || {}, by = loss.by_signal || {}, rows = "";
    Object.keys(by).forEach(function (k) { rows += "<tr><td>" + k + "</td><td>" + by[k] + "</td></tr>"; });
    document.getElementById("loss-rows").innerHTML = rows || "<tr><td>none</td><td>0</td></tr>";
    set("lost", String(loss.lost_samples || 0) + (loss.lost_fraction ? " (" + (100 * loss.lost_fraction).toFixed(2) + " %)" : ""));
    if (s.history && s.history.time.length > 0) {
      var tr = trajectories(s);
      Plotly.react("live-trajectories", tr[0], tr[1], window.onlineId.config);
      var me = meter(s);
      Plotly.react("live-meter", me[0], me[1], window.onlineId.config);
      if (!drawn) { drawn = true; document.body.dataset.liveDrawn = "1"; }
    }
  }
  function poll() {
    fetch("/snapshot.json", {cache: "no-store"}).then(function (r) {
      if (!r.ok) { throw new Error("HTTP " + r.status); }
      return r.json();
    }).then(function (s) {
      var version = JSON.stringify([s.samples, s.time, s.running, s.verdict]);
      if (version !== lastVersion) { lastVersion = version; apply(s); }
      setTimeout(poll, cfg.refresh_ms);
    }).catch(function () {
      // the listener has ended (or the network between): keep what is shown, say so, try again more slowly
      var st = document.getElementById("status");
      if (!/no answer/.test(st.textContent)) { st.textContent += " · no answer from the listener"; }
      setTimeout(poll, 4 * cfg.refresh_ms);
    });
  }
  poll();
})();
