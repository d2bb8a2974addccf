/* lunar_drake mission control: Open MCT plugins for the telemetry server
 * (dictionary, historical and realtime providers, the mission's objects and default
 * layout) and the views of map.js (site map, commands, stereo preview). */
(function () {
  'use strict';
  const NS = 'lunar';
  const MIN = 60 * 1000;

  async function api(path, options) {
    const r = await fetch(path, options);
    let body = null;
    try {
      body = await r.json();
    } catch (e) {
      body = { error: r.statusText };
    }
    if (!r.ok) {
      throw new Error((body && body.error) || r.statusText);
    }
    return body;
  }

  function post(path, body) {
    return api(path, {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify(body)
    });
  }

  /* One WebSocket for every subscription; reconnects and resubscribes. */
  class Realtime {
    constructor() {
      this.listeners = new Map();
      this.messageListeners = new Set();
      this.delivered = {}; // datums handed to subscribers, by key (the browser tests read it)
      this.open();
    }
    open() {
      const proto = location.protocol === 'https:' ? 'wss' : 'ws';
      this.ws = new WebSocket(`${proto}://${location.host}/api/realtime`);
      this.ws.onopen = () => {
        const keys = [...this.listeners.keys()];
        if (keys.length) {
          this.ws.send(JSON.stringify({ subscribe: keys }));
        }
      };
      this.ws.onmessage = (ev) => {
        const msg = JSON.parse(ev.data);
        for (const d of msg.datums || []) {
          for (const cb of this.listeners.get(d.id) || []) {
            cb(d);
            this.delivered[d.id] = (this.delivered[d.id] || 0) + 1;
          }
        }
        for (const cb of this.messageListeners) {
          cb(msg);
        }
      };
      this.ws.onclose = () => setTimeout(() => this.open(), 1000);
    }
    subscribe(key, cb) {
      if (!this.listeners.has(key)) {
        this.listeners.set(key, new Set());
        if (this.ws.readyState === WebSocket.OPEN) {
          this.ws.send(JSON.stringify({ subscribe: [key] }));
        }
      }
      this.listeners.get(key).add(cb);
      return () => {
        const set = this.listeners.get(key);
        if (!set) {
          return;
        }
        set.delete(cb);
        if (set.size === 0) {
          this.listeners.delete(key);
          if (this.ws.readyState === WebSocket.OPEN) {
            this.ws.send(JSON.stringify({ unsubscribe: [key] }));
          }
        }
      };
    }
    onMessage(cb) {
      this.messageListeners.add(cb);
      return () => this.messageListeners.delete(cb);
    }
  }

  function valueMetadata(p) {
    const v = {
      key: 'value',
      name: p.units ? `${p.name} (${p.units})` : p.name,
      units: p.units,
      hints: { range: 1 }
    };
    if (p.format === 'enum') {
      v.format = 'enum';
      v.enumerations = p.enum.map((s, i) => ({ value: i, string: s }));
    } else if (p.format === 'string') {
      v.format = 'string';
    } else if (p.format === 'int') {
      v.format = 'integer';
    } else {
      v.format = 'float';
    }
    return v;
  }

  function id(key) {
    return { namespace: NS, key };
  }

  /* The mission's objects: a root folder, one folder per group of points, the views,
   * plots, tables and the default layout. */
  function missionObjects(dict, info) {
    const objects = {};
    const groups = {};
    const put = (o) => {
      objects[o.identifier.key] = o;
      return o.identifier;
    };
    for (const p of dict.points) {
      const ident = put({
        identifier: id(p.key),
        name: p.name,
        type: 'lunar.telemetry',
        location: `${NS}:group.${p.group}`,
        telemetry: {
          values: [
            valueMetadata(p),
            { key: 'utc', source: 'timestamp', name: 'Time (UTC)', format: 'utc', hints: { domain: 1 } }
          ]
        }
      });
      (groups[p.group] = groups[p.group] || []).push(ident);
    }
    const plot = (key, name, keys) =>
      put({
        identifier: id(key),
        name,
        type: 'telemetry.plot.overlay',
        location: `${NS}:mission`,
        composition: keys.map(id),
        configuration: { series: [] }
      });
    const views = [
      put({ identifier: id('map'), name: 'Site map', type: 'lunar.map', location: `${NS}:mission` }),
      put({ identifier: id('commands'), name: 'Commands', type: 'lunar.commands', location: `${NS}:mission` }),
      put({ identifier: id('camera'), name: 'Stereo preview (left, as received)', type: 'lunar.camera', location: `${NS}:mission` }),
      plot('plot.speed', 'Speed', ['rover.speed', 'rover.cmd_vx']),
      plot('plot.attitude', 'Attitude', ['rover.roll', 'rover.pitch']),
      plot('plot.slip', 'Estimated slip', ['rover.slip']),
      plot('plot.link', 'Link: delay, lost, uplink queue', ['link.delay', 'link.lost', 'link.uplink_queue']),
      plot('plot.power', 'Power', ['rover.soc', 'rover.array_power']),
      put({
        identifier: id('status'),
        name: 'Mode and caution & warning',
        type: 'LadTable',
        location: `${NS}:mission`,
        composition: ['rover.mode', 'rover.safe_reason', 'cw.safed', 'cw.uplink_loss',
          'cw.loss_of_signal', 'cw.earth_below_horizon', 'cw.low_soc', 'rover.soc',
          'ground.goals_reached', 'ground.goals', 'ground.sigma', 'sky.earth_margin',
          'link.received', 'link.lost', 'link.uplink_queue'].map(id)
      }),
      put({
        identifier: id('events'),
        name: 'Ground events',
        type: 'table',
        location: `${NS}:mission`,
        composition: [id('ground.event')],
        configuration: { hiddenColumns: {}, columnWidths: {} }
      })
    ];
    const item = (ident, x, y, width, height) => ({
      type: 'subobject-view', id: `item-${ident.key}`, identifier: ident, x, y, width, height,
      hasFrame: true, fontSize: 'default', font: 'default'
    });
    const [map, commands, camera, speed, attitude, slip, link, power, status, events] = views;
    const layout = put({
      identifier: id('layout'),
      name: `Mission control: ${info.name || 'rover'}`,
      type: 'layout',
      location: `${NS}:mission`,
      composition: views,
      configuration: {
        layoutGrid: [10, 10],
        items: [
          item(map, 0, 0, 56, 52),
          item(commands, 0, 52, 56, 22),
          item(speed, 56, 0, 30, 18),
          item(attitude, 56, 18, 30, 17),
          item(slip, 56, 35, 30, 17),
          item(status, 56, 52, 30, 22),
          item(link, 86, 0, 30, 18),
          item(power, 86, 18, 30, 17),
          item(camera, 86, 35, 30, 17),
          item(events, 86, 52, 30, 22)
        ]
      }
    });
    const folders = Object.entries(groups).map(([g, keys]) =>
      put({ identifier: id(`group.${g}`), name: `Telemetry: ${g}`, type: 'folder', location: `${NS}:mission`, composition: keys })
    );
    put({
      identifier: id('mission'),
      name: `lunar_drake: ${info.name || 'mission'}`,
      type: 'folder',
      location: 'ROOT',
      composition: [layout, ...views, ...folders]
    });
    return objects;
  }

  function plugin(dict, info, realtime) {
    return function install(openmct) {
      const objects = missionObjects(dict, info);
      openmct.objects.addRoot(id('mission'));
      openmct.objects.addProvider(NS, {
        get: (identifier) => Promise.resolve(objects[identifier.key]),
        create: () => Promise.resolve(true),
        update: (o) => {
          objects[o.identifier.key] = o;
          return Promise.resolve(true);
        }
      });
      openmct.types.addType('lunar.telemetry', { name: 'Rover telemetry point', cssClass: 'icon-telemetry' });
      openmct.types.addType('lunar.map', { name: 'Site map', cssClass: 'icon-image' });
      openmct.types.addType('lunar.commands', { name: 'Commands', cssClass: 'icon-command' });
      openmct.types.addType('lunar.camera', { name: 'Stereo preview', cssClass: 'icon-camera' });
      const isOurs = (d) => d.type === 'lunar.telemetry';
      openmct.telemetry.addProvider({
        supportsRequest: isOurs,
        request: (d, options) => {
          const q = new URLSearchParams();
          if (Number.isFinite(options.start)) q.set('start', options.start);
          if (Number.isFinite(options.end)) q.set('end', options.end);
          if (options.strategy === 'latest') q.set('strategy', 'latest');
          return api(`/api/history/${encodeURIComponent(d.identifier.key)}?${q}`);
        },
        supportsSubscribe: isOurs,
        subscribe: (d, callback) => realtime.subscribe(d.identifier.key, callback)
      });
      LunarMap.install(openmct, { api, post, realtime, info });
    };
  }

  async function start(openmct) {
    let info = await api('/api/info');
    if (info.state === 'waiting') {
      const note = document.createElement('div');
      note.id = 'lunar-missing';
      note.textContent = 'The mission is being built (site, world model); the page opens when it runs...';
      document.body.append(note);
      while (info.state === 'waiting') {
        await new Promise((r) => setTimeout(r, 1000));
        info = await api('/api/info');
      }
      note.remove();
    }
    const dict = await api('/api/dictionary');
    const realtime = new Realtime();
    window.lunarRealtime = realtime;
    openmct.setAssetPath('/openmct');
    openmct.install(openmct.plugins.LocalStorage());
    openmct.install(openmct.plugins.Espresso());
    openmct.install(openmct.plugins.UTCTimeSystem());
    openmct.install(openmct.plugins.DisplayLayout());
    openmct.install(openmct.plugins.LADTable());
    openmct.install(plugin(dict, info, realtime));
    openmct.install(openmct.plugins.RemoteClock(id('mission.time')));
    const fixed = {
      name: 'Fixed',
      timeSystem: 'utc',
      bounds: { start: info.epoch_ms, end: info.epoch_ms + 1000 * Math.max(info.duration_s || 0, info.now_s || 0, 60) }
    };
    const live = {
      name: 'Realtime',
      timeSystem: 'utc',
      clock: 'remote-clock',
      clockOffsets: { start: -3 * MIN, end: 10 * 1000 }
    };
    openmct.install(openmct.plugins.Conductor({ menuOptions: info.live ? [live, fixed] : [fixed] }));
    if (!location.hash || location.hash === '#/' || location.hash === '#') {
      location.hash = '#/browse/lunar:mission/lunar:layout';
    }
    openmct.start(document.getElementById('lunar-app'));
  }

  window.LunarDrake = { start, api, post };
})();
