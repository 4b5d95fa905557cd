// Telextiles live textile map. Served by the daemon (telextiles-map); talks to
// /api/map (the textiles) and /api/events (Server-Sent Events).
'use strict';

(function () {
  const TRAIL = 24;          // live positions kept in the trail
  const RANGE = [-1.15, 1.15];

  // Trace order on the plot.
  const T_SEEN = 0, T_UNSEEN = 1, T_SLOTS = 2, T_NEAR = 3, T_DECIDED = 4, T_TRAIL = 5, T_LIVE = 6;

  const S = {
    map: null,          // /api/map document
    fingerprint: null,  // of the map drawn
    instance: null,     // server start id seen last
    connected: false,
    es: null,
    trail: [],          // [{x, y}]
    touch: null,        // last touch message
    contact: false,
    decision: null,
    roller: null,
    felt: null,
    peers: new Map(),
    touches: 0,         // touch messages received (tests read it)
    pending: false,     // a redraw of the live layer is scheduled
    fetching: null,
  };

  const $ = (id) => document.getElementById(id);
  const gd = () => $('map');

  function setStatus(kind, text) {
    const el = $('status');
    el.className = 'status ' + kind;
    el.textContent = text;
  }

  // ---------------------------------------------------------------- the map

  // A peer as the page keeps it: address, path (direct/relay), round trip.
  function peerInfo(m) {
    return { addr: m.addr, path: m.path, rtt_ms: m.rtt_ms };
  }

  function esc(s) {
    return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
  }

  function baseTraces(m) {
    const seen = m.textiles.filter((t) => t.seen);
    const unseen = m.textiles.filter((t) => !t.seen);
    const pts = (list) => ({
      x: list.map((t) => t.x), y: list.map((t) => t.y),
      customdata: list.map((t) => t.i), text: list.map((t) => t.name),
    });
    const slotEntries = m.roller.slots.map((e) => m.textiles[e]);
    return [
      Object.assign(pts(seen), {
        name: 'seen (trained on)', type: 'scatter', mode: 'markers', hoverinfo: 'none',
        marker: { symbol: 'circle', size: 9, color: '#4f7cc2', line: { width: 1, color: '#fff' } },
      }),
      Object.assign(pts(unseen), {
        name: 'unseen', type: 'scatter', mode: 'markers', hoverinfo: 'none',
        marker: { symbol: 'diamond-open', size: 10, color: '#d9822b', line: { width: 2 } },
      }),
      {
        name: 'roller slot', type: 'scatter', mode: 'markers+text', hoverinfo: 'none',
        x: slotEntries.map((t) => t.x), y: slotEntries.map((t) => t.y),
        customdata: slotEntries.map((t) => t.i),
        text: m.roller.slots.map((_, k) => String(k)),
        textposition: 'top right', textfont: { size: 11, color: '#2b7a3d' },
        marker: { symbol: 'square-open', size: 17, color: '#2b7a3d', line: { width: 2 } },
      },
      {
        name: 'nearest to touch', type: 'scatter', mode: 'markers', hoverinfo: 'skip',
        x: [], y: [], marker: { symbol: 'circle-open', size: 24, color: '#c2185b', line: { width: 2.5 } },
      },
      {
        name: 'decided', type: 'scatter', mode: 'markers', hoverinfo: 'skip',
        x: [], y: [], marker: { symbol: 'star', size: 20, color: '#f2b705', line: { width: 1, color: '#7a5200' } },
      },
      {
        name: 'trail', type: 'scatter', mode: 'lines+markers', hoverinfo: 'skip', showlegend: false,
        x: [], y: [], line: { color: 'rgba(211,47,47,0.35)', width: 2 },
        marker: { size: [], color: 'rgba(211,47,47,0.35)' },
      },
      {
        name: 'live touch', type: 'scatter', mode: 'markers', hoverinfo: 'skip',
        x: [], y: [], marker: { symbol: 'circle', size: 16, color: '#d32f2f', line: { width: 2, color: '#fff' } },
      },
    ];
  }

  function layout() {
    return {
      margin: { l: 40, r: 16, t: 16, b: 36 },
      dragmode: 'zoom', hovermode: 'closest', hoverdistance: 14,
      xaxis: { range: RANGE.slice(), zeroline: false, title: { text: 'map x (UMAP)' } },
      yaxis: { range: RANGE.slice(), zeroline: false, title: { text: 'map y' }, scaleanchor: 'x' },
      legend: { orientation: 'h', x: 0, y: 1.0, yanchor: 'bottom' },
      paper_bgcolor: '#f6f7f9', plot_bgcolor: '#fff',
      uirevision: 'keep',  // live updates keep the user's zoom
    };
  }

  const config = {
    responsive: true, displaylogo: false, scrollZoom: false, showTips: false,
    modeBarButtonsToRemove: ['lasso2d', 'select2d', 'autoScale2d'],
  };

  async function loadMap() {
    if (S.fetching) return S.fetching;
    S.fetching = (async () => {
      for (let attempt = 0; ; attempt++) {
        try {
          const r = await fetch('/api/map', { cache: 'no-store' });
          if (!r.ok) throw new Error('HTTP ' + r.status);
          const m = await r.json();
          draw(m);
          return m;
        } catch (e) {
          setStatus('reconnecting', 'reconnecting… (map: ' + e.message + ')');
          await new Promise((res) => setTimeout(res, Math.min(500 * (attempt + 1), 3000)));
        }
      }
    })();
    try { return await S.fetching; } finally { S.fetching = null; }
  }

  function draw(m) {
    const first = S.map === null;
    S.map = m;
    S.fingerprint = m.fingerprint;
    Plotly.react(gd(), baseTraces(m), layout(), config);
    if (first) {
      gd().on('plotly_hover', onHover);
      gd().on('plotly_unhover', hideTip);
      gd().on('plotly_relayout', hideTip);
    }
    gd().dataset.fingerprint = m.fingerprint;
    gd().dataset.points = String(m.textiles.length);
    renderPanel();
    scheduleLive();
  }

  function resetView() {
    Plotly.relayout(gd(), { 'xaxis.range': RANGE.slice(), 'yaxis.range': RANGE.slice() });
  }

  // ------------------------------------------------------------------ hover

  function onHover(ev) {
    const pt = ev.points && ev.points[0];
    if (!pt || pt.customdata === undefined || !S.map) return;
    const t = S.map.textiles[pt.customdata];
    if (!t) return;
    const attrs = t.attributes.map((a) =>
      '<tr><td>' + esc(a.name) + '</td><td><span class="bar" style="width:' +
      Math.round(Math.max(0, Math.min(1, a.value)) * 60) + 'px"></span> ' + a.value.toFixed(2) + '</td></tr>').join('');
    const slot = t.slot !== null ? 'roller slot ' + t.slot : 'not on the roller (nearest slot ' + t.nearest_slot + ')';
    $('tip-text').innerHTML =
      '<div class="name">' + esc(t.name) + '</div>' +
      '<div class="meta">' + esc(t.id) + ' · ' + esc(t.structure) + ' · ' + (t.seen ? 'seen' : 'unseen') + ' · ' + esc(slot) + '</div>' +
      (attrs ? '<table>' + attrs + '</table>' : '');
    const img = $('tip-img');
    if (t.texture) {
      img.classList.remove('none');
      if (img.getAttribute('src') !== t.texture) img.src = t.texture;
      img.alt = 'texture of ' + t.name;
    } else {
      img.classList.add('none');
      img.removeAttribute('src');
    }
    const tip = $('tip');
    tip.hidden = false;
    tip.dataset.id = t.id;
    let cx, cy;
    if (ev.event && ev.event.clientX !== undefined) {
      cx = ev.event.clientX; cy = ev.event.clientY;
    } else {
      const p = pixelOf(t.x, t.y); cx = p.x; cy = p.y;
    }
    const w = tip.offsetWidth, h = tip.offsetHeight;
    let left = cx + 16, top = cy + 16;
    if (left + w > window.innerWidth - 4) left = cx - w - 16;
    if (top + h > window.innerHeight - 4) top = cy - h - 16;
    tip.style.left = Math.max(4, left) + 'px';
    tip.style.top = Math.max(4, top) + 'px';
  }

  function hideTip() { $('tip').hidden = true; }

  // Client pixel position of map coordinates (for tooltips and tests).
  function pixelOf(x, y) {
    const fl = gd()._fullLayout;
    const box = gd().getBoundingClientRect();
    return {
      x: box.left + fl.xaxis._offset + fl.xaxis.l2p(x),
      y: box.top + fl.yaxis._offset + fl.yaxis.l2p(y),
    };
  }

  // ------------------------------------------------------------- live layer

  function scheduleLive() {
    if (S.pending) return;
    S.pending = true;
    requestAnimationFrame(() => { S.pending = false; drawLive(); });
  }

  function drawLive() {
    if (!S.map) return;
    const m = S.map;
    const near = S.touch ? S.touch.nearest.filter((n) => m.textiles[n.i]) : [];
    const dec = S.decision && S.decision.i !== null && m.textiles[S.decision.i] ? [m.textiles[S.decision.i]] : [];
    const n = S.trail.length;
    const liveColor = S.contact ? '#d32f2f' : '#9e9e9e';
    Plotly.restyle(gd(), {
      x: [near.map((k) => m.textiles[k.i].x), dec.map((t) => t.x), S.trail.map((p) => p.x), S.touch ? [S.touch.x] : []],
      y: [near.map((k) => m.textiles[k.i].y), dec.map((t) => t.y), S.trail.map((p) => p.y), S.touch ? [S.touch.y] : []],
      'marker.size': [24, 20, S.trail.map((_, k) => 3 + 6 * (k + 1) / Math.max(1, n)), 16],
      'marker.color': ['#c2185b', '#f2b705', 'rgba(211,47,47,0.35)', liveColor],
    }, [T_NEAR, T_DECIDED, T_TRAIL, T_LIVE]);
    const el = gd();
    if (S.touch) {
      el.dataset.liveX = String(S.touch.x);
      el.dataset.liveY = String(S.touch.y);
    }
    el.dataset.touches = String(S.touches);
  }

  function renderPanel() {
    const m = S.map;
    if (S.touch) {
      const who = S.touch.peer ? 'from ' + S.touch.peer : 'local';
      $('touch').className = '';
      $('touch').textContent = (S.contact ? 'touching' : 'lifted') + ' (' + who + ') at (' +
        S.touch.x.toFixed(2) + ', ' + S.touch.y.toFixed(2) + ')';
      $('nearest').innerHTML = S.touch.nearest.map((n) =>
        '<li>' + esc(n.name) + ' <span class="muted">' + esc(n.id) + ' · d ' + n.d.toFixed(3) + '</span></li>').join('');
    } else {
      $('touch').className = 'muted';
      $('touch').textContent = S.contact ? 'touching' : 'no touch yet';
      $('nearest').innerHTML = '';
    }
    if (S.decision) {
      const d = S.decision;
      // A fabric the index does not have: say so, and name the nearest
      // known one the roller turns to.
      $('decision').className = d.unknown ? 'big unknown' : 'big';
      $('decision').textContent = (d.unknown ? 'unknown fabric; nearest known: ' : '') +
        (d.name || d.id) + ' → slot ' + d.slot;
      $('decision').title = 'distance ' + Number(d.distance).toFixed(3) + ', ' + Number(d.latency_ms).toFixed(0) + ' ms';
    } else {
      $('decision').className = 'muted';
      $('decision').textContent = 'none yet';
    }
    drawWheel(m, S.roller);
    if (S.felt) {
      const f = S.felt;
      $('felt').className = '';
      $('felt').textContent = 'last press felt ' + Number(f.felt_ms).toFixed(0) +
        ' ms after contact (at rest at slot ' + f.slot + ')';
    }
    if (S.roller) {
      const r = S.roller;
      $('roller').className = '';
      $('roller').textContent = Number(r.angle_deg).toFixed(1) + '° ' +
        (r.arrived ? 'at slot ' + r.slot : 'moving' + (r.target_slot !== null && r.target_slot !== undefined ? ' to slot ' + r.target_slot : '')) +
        (m && r.slot !== null && m.textiles[m.roller.slots[r.slot]] ? ' (' + m.textiles[m.roller.slots[r.slot]].name + ')' : '');
    }
    const peers = $('peers');
    if (S.peers.size === 0) {
      peers.innerHTML = '<li class="muted">none connected</li>';
    } else {
      peers.innerHTML = [...S.peers.entries()].map(([p, i]) =>
        '<li>' + esc(p) + (i.path ? ' <span class="path">' + esc(i.path) +
          (i.rtt_ms !== null && i.rtt_ms !== undefined ? ' · ' + Number(i.rtt_ms).toFixed(1) + ' ms' : '') + '</span>' : '') +
        (i.addr ? ' <span class="muted">' + esc(i.addr) + '</span>' : '') + '</li>').join('');
    }
  }

  // The wheel seen from the finger: slot k sits at k * 360 / N degrees on
  // the plate, the finger at the top; the plate is turned by the roller's
  // angle, so the sample under the finger is at the top. The target slot
  // is filled, the one under the finger outlined.
  function drawWheel(m, r) {
    const svg = $('wheel');
    if (!m || !m.roller || !m.roller.slots.length) { svg.innerHTML = ''; return; }
    const n = m.roller.slots.length;
    const angle = r ? Number(r.angle_deg) : 0;
    const target = r && r.target_slot !== null && r.target_slot !== undefined ? Number(r.target_slot) : -1;
    const here = r && r.slot !== null && r.slot !== undefined ? Number(r.slot) : -1;
    const R = 46, rs = Math.max(4, Math.min(9, Math.PI * R / n * 0.8));
    let g = '<circle class="rim" r="56"></circle>';
    for (let k = 0; k < n; k++) {
      const a = (k * 360 / n) * Math.PI / 180;
      const x = (R * Math.sin(a)).toFixed(2), y = (-R * Math.cos(a)).toFixed(2);
      const cls = 'slot' + (k === target ? ' target' : '') + (k === here ? ' here' : '');
      g += '<g data-slot="' + k + '"><circle class="' + cls + '" cx="' + x + '" cy="' + y + '" r="' + rs.toFixed(2) + '"></circle>' +
        '<text x="' + x + '" y="' + y + '">' + k + '</text></g>';
    }
    svg.innerHTML = '<g id="plate" data-angle="' + angle.toFixed(1) + '" transform="rotate(' + (-angle).toFixed(2) + ')">' + g + '</g>' +
      '<path class="finger" d="M0,-58 l-5,-6 h10 z"></path>';
  }

  function onTouch(msg) {
    S.touches++;
    S.touch = msg;
    S.trail.push({ x: msg.x, y: msg.y });
    if (S.trail.length > TRAIL) S.trail.splice(0, S.trail.length - TRAIL);
  }

  function onMessage(msg) {
    switch (msg.type) {
      case 'hello': {
        const restarted = S.instance !== null && S.instance !== msg.instance;
        S.instance = msg.instance;
        if (msg.fingerprint !== S.fingerprint) {
          // Another index: the old live state means nothing on it (the
          // state message that follows brings the new one).
          S.trail = [];
          S.touch = null;
          S.decision = null;
          setStatus('connecting', 'loading map…');
          loadMap().then(() => connected(msg));
        } else {
          connected(msg);
          if (restarted) console.info('daemon restarted; same index');
        }
        return;
      }
      case 'state':
        S.trail = [];
        S.touch = null;
        if (msg.touch) onTouch(msg.touch);
        S.contact = !!(msg.contact && msg.contact.on);
        S.decision = msg.decision || null;
        S.roller = msg.roller || null;
        S.felt = msg.felt || null;
        S.peers = new Map((msg.peers || []).map((p) => [p.peer, peerInfo(p)]));
        break;
      case 'touch': onTouch(msg); break;
      case 'contact':
        S.contact = msg.on;
        if (msg.on) { S.trail = []; }
        break;
      case 'decision': S.decision = msg; break;
      case 'roller': S.roller = msg; break;
      case 'felt': S.felt = msg; break;
      case 'peer':
        if (msg.up) S.peers.set(msg.peer, peerInfo(msg)); else S.peers.delete(msg.peer);
        break;
      case 'lagged': break;
      case 'error': console.warn('daemon:', msg.source, msg.message); break;
      default: return;
    }
    renderPanel();
    scheduleLive();
  }

  function connected(hello) {
    S.connected = true;
    setStatus('connected', 'connected · ' + hello.textiles + ' textiles · index ' + String(hello.fingerprint).slice(0, 8));
  }

  // ------------------------------------------------------------ connection

  function connect() {
    if (S.es) S.es.close();
    const es = new EventSource('/api/events');
    S.es = es;
    es.onmessage = (e) => {
      let msg;
      try { msg = JSON.parse(e.data); } catch (_) { return; }
      onMessage(msg);
    };
    es.onerror = () => {
      S.connected = false;
      setStatus('reconnecting', 'reconnecting…');
      // EventSource retries by itself while CONNECTING; if it gave up
      // (e.g. an HTTP error status), start over.
      if (es.readyState === EventSource.CLOSED) {
        setTimeout(() => { if (S.es === es) connect(); }, 1000);
      }
    };
  }

  window.telextilesMap = {
    state: S,
    pixelOf,
    // Client pixel position of a textile's point, by id.
    pointPixel(id) {
      const t = S.map && S.map.textiles.find((x) => x.id === id);
      return t ? pixelOf(t.x, t.y) : null;
    },
    resetView,
  };

  document.addEventListener('DOMContentLoaded', () => {
    $('reset').addEventListener('click', resetView);
    window.addEventListener('blur', hideTip);
    if (typeof Plotly === 'undefined') {
      setStatus('error', 'chart library failed to load');
      return;
    }
    connect();
  });
})();
