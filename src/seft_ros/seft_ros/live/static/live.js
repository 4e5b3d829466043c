/* seft live view: the page's side of the feed (seft_ros/live/web.py).
 *
 * The feed sends {type: "hello"} (the run, its plots, the analytical reference, every shown
 * sample so far, the state) and then {type: "data"} with what is new. Samples are placed on
 * the run's grid of shown steps (step / decimation), so the test, its commands and the
 * analytical reference (drawn ahead, dashed) line up; a sample the view missed is a gap.
 * Each plot's container carries data-points (the samples of its first series of the test
 * drawn) for a test to read.
 */
(function () {
  'use strict';
  const $ = (id) => document.getElementById(id);
  const COLORS = { test: ['#60a5fa', '#f472b6', '#34d399', '#fbbf24', '#a78bfa', '#f87171'],
                   command: '#fbbf24', reference: '#e5e7eb' };
  const REDRAW_MS = 200;
  const PLOT_HEIGHT = 230;
  const st = { runId: null, decim: 1, dt: 0.002, x: [], plots: [], byKey: {},
               latest: {}, status: {}, timer: null, stopAsked: false };

  function connect() {
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const ws = new WebSocket(`${proto}//${location.host}/live${location.search}`);
    st.ws = ws;
    ws.onopen = () => setConn(true);
    ws.onclose = () => { setConn(false); setTimeout(connect, 1000); };
    ws.onmessage = (ev) => {
      const msg = JSON.parse(ev.data);
      if (msg.type === 'hello') hello(msg);
      else if (msg.type === 'data') data(msg);
      else if (msg.type === 'stop') stopReply(msg);
    };
  }

  function setConn(on) {
    const c = $('conn');
    c.className = 'conn ' + (on ? 'on' : 'off');
    c.title = on ? 'connected to the live view' : 'not connected (retrying)';
  }

  function hello(msg) {
    const run = msg.run || {};
    st.runId = msg.run_id;
    st.decim = run.decimation || 1;
    st.dt = run.dt || 0.002;
    st.latest = {};
    const ref = msg.reference || {};
    const refLen = Object.values(ref).reduce((m, a) => Math.max(m, a.length), 0);
    const nSteps = (msg.status && msg.status.n_steps) || 0;
    const n = Math.max(refLen, Math.ceil(nSteps / st.decim));
    st.x = [];
    for (let i = 0; i < n; i++) st.x.push(i * st.decim * st.dt);
    const box = $('plots');
    box.textContent = '';
    st.plots.forEach((p) => p.u.destroy());
    st.plots = [];
    st.byKey = {};
    (msg.plots || []).forEach((spec) => {
      const div = document.createElement('div');
      div.className = 'plot';
      div.dataset.title = spec.title;
      div.dataset.points = '0';
      const h = document.createElement('h2');
      h.textContent = `${spec.title} [${spec.unit}]`;
      const now = document.createElement('span');
      now.className = 'now';
      h.appendChild(now);
      div.appendChild(h);
      box.appendChild(div);
      const plot = { spec, div, now, data: [st.x], points: 0, dirty: true, lastT: null };
      const series = [{ label: 't [s]' }];
      let testIdx = 0;
      spec.series.forEach((s, i) => {
        const arr = new Array(n).fill(null);
        if (s.style === 'reference' && ref[s.key]) {
          ref[s.key].forEach((v, k) => { arr[k] = v === null ? null : v * spec.scale; });
        }
        plot.data.push(arr);
        const color = s.style === 'test' ? COLORS.test[testIdx++ % COLORS.test.length]
          : COLORS[s.style];
        series.push({ label: s.label, stroke: color, width: s.style === 'test' ? 2 : 1.5,
                      dash: s.style === 'reference' ? [8, 5] : undefined, spanGaps: false,
                      value: (u, v) => (v == null ? '–' : v.toPrecision(4)) });
        // data-points counts the samples of the plot's first series of the test
        const counted = s.style !== 'reference' && !plot.counted;
        if (counted) plot.counted = true;
        (st.byKey[s.key] = st.byKey[s.key] || []).push({ plot, idx: i + 1, counted });
      });
      plot.opts = {
        width: 300, height: PLOT_HEIGHT,
        scales: { x: { time: false } },
        series,
        axes: [
          { stroke: '#98a2b3', grid: { stroke: '#2a313b' }, label: 't [s]' },
          { stroke: '#98a2b3', grid: { stroke: '#2a313b' }, label: spec.unit, size: 60 },
        ],
        legend: { show: true },
      };
      st.plots.push(plot);
    });
    // every panel placed first, so that each plot takes its own panel's width
    st.plots.forEach((p) => {
      p.opts.width = plotWidth(p);
      p.u = new uPlot(p.opts, p.data, p.div);
    });
    addSeries(msg.series || {});
    showStatus(msg.status || {}, msg.events || [], run);
    const stop = $('stop');
    stop.hidden = !msg.stop;
    stop.disabled = false;
    scheduleDraw();
  }

  function ensureLength(n) {
    while (st.x.length < n) {
      st.x.push(st.x.length * st.decim * st.dt);
      st.plots.forEach((p) => { for (let i = 1; i < p.data.length; i++) p.data[i].push(null); });
    }
  }

  function addSeries(series) {
    Object.entries(series).forEach(([key, [steps, values]]) => {
      if (steps.length) st.latest[key] = values[values.length - 1];
      const targets = st.byKey[key];
      if (!targets) return;
      for (let i = 0; i < steps.length; i++) {
        const slot = Math.round(steps[i] / st.decim);
        ensureLength(slot + 1);
        targets.forEach((t) => {
          const v = values[i];
          t.plot.data[t.idx][slot] = v === null ? null : v * t.plot.spec.scale;
          if (t.counted) { t.plot.points++; t.plot.lastT = steps[i] * st.dt; }
          t.plot.dirty = true;
        });
      }
    });
  }

  function data(msg) {
    if (msg.run_id !== st.runId) return;
    addSeries(msg.series || {});
    if (msg.status) showStatus(msg.status, msg.events || [], null);
    scheduleDraw();
  }

  function scheduleDraw() {
    if (st.timer) return;
    st.timer = setTimeout(() => {
      st.timer = null;
      st.plots.forEach((p) => {
        if (!p.dirty) return;
        p.dirty = false;
        p.u.setData(p.data);
        p.div.dataset.points = String(p.points);
        if (p.lastT !== null) p.now.textContent = `t = ${p.lastT.toFixed(2)} s`;
      });
      showTiming();
    }, REDRAW_MS);
  }

  function showStatus(s, events, run) {
    st.status = s;
    const state = $('state');
    state.textContent = s.state || 'waiting';
    state.className = 'state ' + (s.state || 'waiting');
    state.dataset.state = s.state || 'waiting';
    if (run) {
      $('run').textContent = run.label ? `${run.label} · ${run.mode}` : 'no run yet';
    }
    const n = s.n_steps || 0;
    const pct = n ? ` (${Math.round(100 * s.step / n)} %)` : '';
    $('progress').textContent = s.state === 'waiting' ? ''
      : `step ${s.step}${n ? ' / ' + n : ''}${pct} · t = ${(s.t_s || 0).toFixed(2)} s`
        + (s.bag_closed ? ' · bag closed' + (s.lost ? `, ${s.lost} lost` : '') : '');
    const reason = $('reason');
    const ended = s.state === 'aborted' || s.state === 'failed';
    reason.hidden = !ended;
    reason.textContent = ended ? `${s.state}: ${s.reason}` : '';
    // samples read at a sensor's range (flagged; the report says what was done with them)
    const atRange = [];
    Object.entries(s.at_range || {}).forEach(([rig, counts]) => {
      Object.entries(counts).forEach(([channel, count]) => {
        atRange.push(`${rig ? rig + ' ' : ''}${channel} ${count}`);
      });
    });
    $('range').hidden = !atRange.length;
    $('range').textContent = atRange.length ? 'at sensor range: ' + atRange.join(', ') : '';
    const links = Object.entries(s.link || {}).map(([peer, l]) =>
      `${peer}: round trip ${fmt(l.round_trip_p50_ms)} / ${fmt(l.round_trip_p99_ms)} ms, `
      + `offset ${fmt(l.offset_ms)} ms`);
    $('link').textContent = links.join(' · ');
    const list = $('events');
    list.textContent = '';
    events.slice(-8).reverse().forEach((e) => {
      const li = document.createElement('li');
      li.className = e.level;
      li.textContent = `t = ${e.t_s.toFixed(3)} s · ${e.node}: ${e.message}`;
      list.appendChild(li);
    });
    if (ended || s.state === 'done') $('stop').disabled = true;
    showTiming();
  }

  function fmt(v) { return v == null ? '–' : v.toFixed(2); }

  function showTiming() {
    // missed deadlines and stale inputs: the nodes' final counts, else the running totals
    const s = st.status || {};
    const missed = Object.assign({}, s.missed_deadlines || {});
    Object.entries(st.latest).forEach(([key, v]) => {
      const m = key.match(/^(.*)\/seft\/live\/timing\/(\w+)\.missed_deadlines$/);
      if (m) {
        const node = (m[1] ? m[1].slice(1) + '/' : '') + m[2];
        if (!(node in missed)) missed[node] = v;
      }
    });
    const total = Object.values(missed).reduce((a, b) => a + (b || 0), 0);
    const lat = Object.entries(st.latest).filter(([k]) => k.endsWith('.loop_latency_s'))
      .map(([, v]) => v).filter((v) => v !== null);
    $('timing').textContent = Object.keys(missed).length
      ? `missed deadlines ${total}` + (lat.length ? ` · loop latency ${(1e3 * Math.max(...lat)).toFixed(2)} ms` : '')
      : '';
  }

  function stopReply(msg) {
    const r = $('reason');
    r.hidden = false;
    r.textContent = msg.message;
    if (!msg.ok) $('stop').disabled = false;
  }

  $('stop').addEventListener('click', () => {
    if (!window.confirm('Stop the test? The rig goes to its safe state.')) return;
    $('stop').disabled = true;
    st.ws.send(JSON.stringify({ op: 'stop' }));
  });

  function plotWidth(p) { return Math.max(300, p.div.clientWidth - 16); }

  window.addEventListener('resize', () => {
    st.plots.forEach((p) => p.u.setSize({ width: plotWidth(p), height: PLOT_HEIGHT }));
  });

  connect();
}());
