/* lunar_drake mission control: the site map (hillshade of the ground's map, costmap with
 * unconfirmed cells, the ground's track, goals, the plan, NSS heat layer; click to
 * preview and send a goal), the command panel and the stereo preview, as Open MCT views. */
(function () {
  'use strict';
  const GOAL_COLORS = { pending: '#ccc', active: '#ffd34d', reached: '#4caf50', failed: '#f44336' };

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    Object.assign(e, attrs || {});
    for (const c of children) {
      e.append(c);
    }
    return e;
  }

  function heat(v, lo, hi) {
    const t = Math.max(0, Math.min(1, (v - lo) / (hi - lo || 1)));
    const r = Math.round(255 * Math.min(1, 2 * t));
    const b = Math.round(255 * Math.min(1, 2 * (1 - t)));
    return `rgba(${r},${Math.round(120 * (1 - Math.abs(2 * t - 1)))},${b},0.85)`;
  }

  class SiteMap {
    constructor(element, ctx) {
      this.ctx = ctx;
      this.state = null;
      this.view = null; // {cx, cy, scale px/m}
      this.preview = null; // {x, y, path, error}
      this.layers = { costmap: true, track: true, plan: true, science: true };
      this.hill = new Image();
      this.cost = new Image();
      this.costVersion = -1;
      this.root = el('div', { className: 'lunar-map' });
      this.canvas = el('canvas', { className: 'lunar-map-canvas' });
      this.status = el('span', { className: 'status' });
      this.sendBtn = el('button', { className: 'lunar-btn go', textContent: 'Send goal', hidden: true });
      this.cancelBtn = el('button', { className: 'lunar-btn', textContent: 'Cancel', hidden: true });
      const bar = el('div', { className: 'bar' });
      for (const name of Object.keys(this.layers)) {
        const box = el('input', { type: 'checkbox', checked: true });
        box.dataset.layer = name;
        box.onchange = () => {
          this.layers[name] = box.checked;
          this.draw();
        };
        bar.append(el('label', {}, box, ` ${name}`));
      }
      if (ctx.info.instructor) {
        const box = el('input', { type: 'checkbox', checked: true });
        box.dataset.layer = 'instructor';
        box.onchange = () => {
          this.layers.instructor = box.checked;
          this.draw();
        };
        bar.append(el('label', { className: 'instructor' }, box, ' instructor (TRUTH)'));
      }
      this.heatSelect = el('select', { title: 'heat layer' });
      this.heatSelect.onchange = () => this.draw();
      bar.append(this.heatSelect, this.sendBtn, this.cancelBtn, this.status);
      this.root.append(this.canvas, bar);
      element.append(this.root);
      this.sendBtn.onclick = () => this.sendGoal();
      this.cancelBtn.onclick = () => this.clearPreview();
      this.hill.onload = () => this.draw();
      this.cost.onload = () => this.draw();
      this.hill.src = '/api/map/hillshade.png';
      window.lunarMap = this; // for the browser tests and the console
      this.bindMouse();
      this.timer = setInterval(() => this.refresh(), 1000);
      this.resize = new ResizeObserver(() => this.draw());
      this.resize.observe(this.canvas);
      this.refresh();
    }
    destroy() {
      clearInterval(this.timer);
      this.resize.disconnect();
    }
    async refresh() {
      try {
        this.state = await this.ctx.api('/api/map');
      } catch (e) {
        return;
      }
      const cm = this.state.costmap;
      if (cm && cm.version !== this.costVersion) {
        this.costVersion = cm.version;
        this.cost.src = `/api/map/costmap.png?v=${cm.version}`;
      }
      if (this.pendingGoal) {
        this.trackAck();
      }
      this.draw();
    }
    fit() {
      const ext = this.state && this.state.extent_m;
      if (!ext) {
        return null;
      }
      const w = this.canvas.clientWidth;
      const h = this.canvas.clientHeight;
      const s = Math.min(w / (ext[1] - ext[0]), h / (ext[3] - ext[2]));
      return { cx: (ext[0] + ext[1]) / 2, cy: (ext[2] + ext[3]) / 2, scale: s };
    }
    toPx(x, y) {
      const v = this.view;
      return [this.canvas.clientWidth / 2 + (x - v.cx) * v.scale, this.canvas.clientHeight / 2 - (y - v.cy) * v.scale];
    }
    toSite(px, py) {
      const v = this.view;
      return [v.cx + (px - this.canvas.clientWidth / 2) / v.scale, v.cy - (py - this.canvas.clientHeight / 2) / v.scale];
    }
    bindMouse() {
      let drag = null;
      this.canvas.addEventListener('mousedown', (e) => {
        drag = { x: e.offsetX, y: e.offsetY, moved: false };
      });
      this.canvas.addEventListener('mousemove', (e) => {
        if (!drag || !this.view) {
          return;
        }
        const dx = e.offsetX - drag.x;
        const dy = e.offsetY - drag.y;
        if (Math.abs(dx) + Math.abs(dy) > 3) {
          drag.moved = true;
          this.view.cx -= dx / this.view.scale;
          this.view.cy += dy / this.view.scale;
          drag.x = e.offsetX;
          drag.y = e.offsetY;
          this.draw();
        }
      });
      this.canvas.addEventListener('mouseup', (e) => {
        if (drag && !drag.moved && this.view) {
          const [x, y] = this.toSite(e.offsetX, e.offsetY);
          this.previewGoal(x, y);
        }
        drag = null;
      });
      this.canvas.addEventListener('wheel', (e) => {
        if (!this.view) {
          return;
        }
        e.preventDefault();
        const [x, y] = this.toSite(e.offsetX, e.offsetY);
        const k = e.deltaY < 0 ? 1.25 : 0.8;
        this.view.scale *= k;
        this.view.cx = x - (x - this.view.cx) / k;
        this.view.cy = y - (y - this.view.cy) / k;
        this.draw();
      });
    }
    async previewGoal(x, y) {
      this.preview = { x, y, path: null, error: null };
      this.setStatus(`goal (${x.toFixed(1)}, ${y.toFixed(1)}) m: planning the preview...`);
      this.draw();
      try {
        const r = await this.ctx.post('/api/preview', { x_m: x, y_m: y });
        if (!this.preview || this.preview.x !== x) {
          return;
        }
        this.preview.path = r.path;
        this.sendBtn.hidden = false;
        this.cancelBtn.hidden = false;
        this.setStatus(`goal (${x.toFixed(1)}, ${y.toFixed(1)}) m: preview drawn; send it?`);
      } catch (err) {
        this.preview.error = err.message;
        this.cancelBtn.hidden = false;
        this.setStatus(`refused: ${err.message}`, true);
      }
      this.draw();
    }
    clearPreview() {
      this.preview = null;
      this.sendBtn.hidden = true;
      this.cancelBtn.hidden = true;
      this.setStatus('');
      this.draw();
    }
    async sendGoal() {
      const p = this.preview;
      if (!p) {
        return;
      }
      this.sendBtn.hidden = true;
      try {
        const r = await this.ctx.post('/api/command', { action: 'goal', x_m: p.x, y_m: p.y });
        this.pendingGoal = { x: p.x, y: p.y, sentPlanSeq: this.state ? this.state.plan_seq : -1, t: r.t_s };
        this.preview = null;
        this.cancelBtn.hidden = true;
        this.setStatus(`goal (${p.x.toFixed(1)}, ${p.y.toFixed(1)}) m sent at t = ${r.t_s.toFixed(1)} s; going up the uplink...` + (r.warning ? ` WARNING: ${r.warning}` : ''), !!r.warning);
        this.ackState = 'sent';
      } catch (err) {
        this.setStatus(`refused: ${err.message}`, true);
      }
      this.draw();
    }
    trackAck() {
      const g = this.pendingGoal;
      const st = this.state;
      const mine = (st.goals || []).find((q) => Math.abs(q[0] - g.x) < 1e-6 && Math.abs(q[1] - g.y) < 1e-6);
      if (!mine) {
        return;
      }
      if (mine[2] === 'reached' || mine[2] === 'failed') {
        this.setStatus(`goal (${g.x.toFixed(1)}, ${g.y.toFixed(1)}) m ${mine[2]}`, mine[2] === 'failed');
        this.pendingGoal = null;
        return;
      }
      if (mine[2] === 'active' && st.plan_seq >= 0 && st.plan_seq !== g.sentPlanSeq) {
        this.ctx.api('/api/history/rover.motion_seq?strategy=latest').then((rows) => {
          const last = rows[rows.length - 1];
          if (last && last.value >= st.plan_seq && this.pendingGoal === g) {
            this.setStatus(`goal (${g.x.toFixed(1)}, ${g.y.toFixed(1)}) m: acknowledged by the rover (goto seq ${st.plan_seq}); driving`);
            this.root.dataset.ack = 'acknowledged';
          } else if (this.pendingGoal === g) {
            this.setStatus(`goal (${g.x.toFixed(1)}, ${g.y.toFixed(1)}) m: planned, goto seq ${st.plan_seq} sent; waiting for acknowledgement`);
          }
        });
      }
    }
    setStatus(text, bad) {
      this.status.textContent = text;
      this.status.className = bad ? 'status refused' : 'status';
    }
    draw() {
      const c = this.canvas;
      const dpr = window.devicePixelRatio || 1;
      const w = c.clientWidth;
      const h = c.clientHeight;
      if (!w || !h) {
        return;
      }
      c.width = w * dpr;
      c.height = h * dpr;
      const g = c.getContext('2d');
      g.setTransform(dpr, 0, 0, dpr, 0, 0);
      g.fillStyle = '#111';
      g.fillRect(0, 0, w, h);
      if (!this.state || !this.state.extent_m) {
        g.fillStyle = '#888';
        g.fillText('waiting for the site map...', 10, 20);
        return;
      }
      if (!this.view) {
        this.view = this.fit();
      }
      const ext = this.state.extent_m;
      const [x0, y0] = this.toPx(ext[0], ext[3]);
      const [x1, y1] = this.toPx(ext[1], ext[2]);
      if (this.hill.complete && this.hill.naturalWidth) {
        g.drawImage(this.hill, x0, y0, x1 - x0, y1 - y0);
      }
      const cm = this.state.costmap;
      if (this.layers.costmap && cm && this.cost.complete && this.cost.naturalWidth) {
        const [a0, b0] = this.toPx(cm.extent_m[0], cm.extent_m[3]);
        const [a1, b1] = this.toPx(cm.extent_m[1], cm.extent_m[2]);
        g.imageSmoothingEnabled = false;
        g.drawImage(this.cost, a0, b0, a1 - a0, b1 - b0);
        g.imageSmoothingEnabled = true;
      }
      const layers = Object.keys(this.state.science || {});
      if (layers.length && this.heatSelect.options.length !== layers.length) {
        const keep = this.heatSelect.value;
        this.heatSelect.replaceChildren(...layers.map((k) => el('option', { value: k, textContent: this.state.heat_layers[k] || k })));
        if (layers.includes(keep)) this.heatSelect.value = keep;
      }
      const samples = (this.state.science || {})[this.heatSelect.value] || [];
      if (this.layers.science && samples.length) {
        const vals = samples.map((s) => s[2]);
        const lo = Math.min(...vals);
        const hi = Math.max(...vals);
        const r = Math.max(1.5, 0.2 * this.view.scale);
        for (const [x, y, v] of samples) {
          const [px, py] = this.toPx(x, y);
          g.fillStyle = heat(v, lo, hi);
          g.beginPath();
          g.arc(px, py, r, 0, 2 * Math.PI);
          g.fill();
        }
        g.fillStyle = '#ddd';
        g.fillText(`heat: ${lo.toPrecision(3)} (blue) to ${hi.toPrecision(3)} (red)`, 6, 14);
      }
      const line = (pts, color, width, dash) => {
        if (!pts || pts.length < 2) {
          return;
        }
        g.strokeStyle = color;
        g.lineWidth = width;
        g.setLineDash(dash || []);
        g.beginPath();
        pts.forEach(([x, y], i) => {
          const [px, py] = this.toPx(x, y);
          if (i) g.lineTo(px, py);
          else g.moveTo(px, py);
        });
        g.stroke();
        g.setLineDash([]);
      };
      if (this.layers.plan) {
        line(this.state.plan, '#ffd34d', 2, [6, 4]);
      }
      if (this.layers.track) {
        line(this.state.track, '#3cf', 2);
      }
      const truth = this.state.instructor;
      if (truth && this.layers.instructor !== false) {
        // the oracle: drawn apart, magenta and labelled, never mistaken for telemetry
        line(truth.track, '#ff2bd6', 1.5, [2, 3]);
        if (truth.rover) {
          const [px, py] = this.toPx(truth.rover[0], truth.rover[1]);
          g.strokeStyle = '#ff2bd6';
          g.lineWidth = 2;
          g.strokeRect(px - 5, py - 5, 10, 10);
        }
        g.fillStyle = '#ff2bd6';
        g.fillText('INSTRUCTOR OVERLAY: magenta = TRUE track (not known to the ground)', 6, 28);
      }
      if (this.preview) {
        line(this.preview.path, '#fff', 2, [3, 3]);
        const [px, py] = this.toPx(this.preview.x, this.preview.y);
        g.strokeStyle = this.preview.error ? '#f44336' : '#fff';
        g.lineWidth = 2;
        g.beginPath();
        g.moveTo(px - 7, py - 7);
        g.lineTo(px + 7, py + 7);
        g.moveTo(px + 7, py - 7);
        g.lineTo(px - 7, py + 7);
        g.stroke();
      }
      (this.state.goals || []).forEach(([x, y, s], i) => {
        const [px, py] = this.toPx(x, y);
        g.strokeStyle = GOAL_COLORS[s] || '#ccc';
        g.lineWidth = 2;
        g.beginPath();
        g.arc(px, py, 7, 0, 2 * Math.PI);
        g.stroke();
        g.fillStyle = GOAL_COLORS[s] || '#ccc';
        g.fillText(`${i + 1}`, px + 9, py - 6);
      });
      const rover = this.state.rover;
      if (rover) {
        const [px, py] = this.toPx(rover[0], rover[1]);
        g.fillStyle = '#3cf';
        g.beginPath();
        g.arc(px, py, 5, 0, 2 * Math.PI);
        g.fill();
      }
      g.fillStyle = '#aaa';
      g.fillText(`ground's map (${this.ctx.info.map_source || '?'}); click to plan a goal; wheel zooms, drag pans`, 6, h - 6);
    }
  }

  class Commands {
    constructor(element, ctx) {
      this.ctx = ctx;
      const root = el('div', { className: 'lunar-cmd' });
      this.log = el('div', { className: 'log' });
      const num = (name, value) => el('input', { type: 'number', step: 'any', value, name });
      const btn = (text, cls, fn) => {
        const b = el('button', { className: `lunar-btn ${cls || ''}`, textContent: text });
        b.onclick = fn;
        return b;
      };
      const speed = num('speed_mps', 0.2);
      const curv = num('curvature_per_m', 0);
      const dist = num('distance_m', 2);
      const pan = num('pan_deg', 0);
      const tilt = num('tilt_deg', -20);
      const depth = num('depth_m', 0.5);
      root.append(
        el('div', { className: 'row' },
          btn('STOP', 'stop', () => this.send({ action: 'stop' })),
          btn('Resume', 'go', () => this.send({ action: 'resume' })),
          btn('End mission', '', () => this.end())),
        el('div', { className: 'row' }, 'Drive arc: speed', speed, 'm/s, curvature', curv, '1/m, distance', dist, 'm',
          btn('Drive', '', () => this.send({ action: 'drive_arc', speed_mps: +speed.value, curvature_per_m: +curv.value, distance_m: +dist.value }))),
        el('div', { className: 'row' }, 'Mast: pan', pan, 'deg, tilt', tilt, 'deg',
          btn('Point', '', () => this.send({ action: 'point_mast', pan_deg: +pan.value, tilt_deg: +tilt.value })),
          btn('Auto', '', () => this.send({ action: 'point_mast' }))),
        el('div', { className: 'row' }, 'Drill to', depth, 'm', btn('Drill', '', () => this.send({ action: 'drill', depth_m: +depth.value }))),
        this.log
      );
      element.append(root);
    }
    note(text) {
      this.log.textContent = `${text}\n${this.log.textContent}`.slice(0, 4000);
    }
    async send(cmd) {
      try {
        const r = await this.ctx.post('/api/command', cmd);
        this.note(`t=${r.t_s.toFixed(1)} s  ${cmd.action}: queued for the uplink` + (r.warning ? `; WARNING: ${r.warning}` : ''));
      } catch (err) {
        this.note(`${cmd.action}: REFUSED: ${err.message}`);
      }
    }
    async end() {
      try {
        await this.ctx.post('/api/end', {});
        this.note('ending the mission: the run is being written');
      } catch (err) {
        this.note(`end: ${err.message}`);
      }
    }
  }

  class Camera {
    constructor(element, ctx) {
      this.img = el('img', { alt: 'stereo preview' });
      this.caption = el('div', { textContent: 'no stereo frame received yet' });
      element.append(el('div', { className: 'lunar-cam' }, this.img, this.caption));
      this.frame = null;
      this.timer = setInterval(async () => {
        try {
          const s = await ctx.api('/api/map');
          if (s.frame && (!this.frame || s.frame.frame_index !== this.frame.frame_index)) {
            this.frame = s.frame;
            this.img.src = `/api/camera/latest.png?f=${s.frame.frame_index}`;
            this.caption.textContent = `frame ${s.frame.frame_index}, received t = ${s.frame.t_received_s.toFixed(1)} s`;
          }
        } catch (e) {
          /* the server may be gone; keep trying */
        }
      }, 1000);
    }
    destroy() {
      clearInterval(this.timer);
    }
  }

  function viewProvider(key, name, type, Cls, ctx) {
    return {
      key,
      name,
      canView: (d) => d.type === type,
      view: () => {
        let inst = null;
        return {
          show: (element) => {
            inst = new Cls(element, ctx);
          },
          destroy: () => inst && inst.destroy && inst.destroy()
        };
      }
    };
  }

  window.LunarMap = {
    install(openmct, ctx) {
      openmct.objectViews.addProvider(viewProvider('lunar.map.view', 'Site map', 'lunar.map', SiteMap, ctx));
      openmct.objectViews.addProvider(viewProvider('lunar.commands.view', 'Commands', 'lunar.commands', Commands, ctx));
      openmct.objectViews.addProvider(viewProvider('lunar.camera.view', 'Stereo preview', 'lunar.camera', Camera, ctx));
    }
  };
})();
