// Minimal host shell for @foxglove/studio-base 1.48.0, modelled on packages/studio-web/src/Root.tsx
// of foxglove/studio (which is not published to npm). Everything below is plumbing the web app
// normally provides: app configuration in localStorage, a layout storage, the data sources.
// The Studio code itself (window.App etc., from studio-base's assets/index.js) is untouched.
(function () {
  "use strict";
  const S = window; // studio-base's UMD bundle put its exports on window
  const h = React.createElement;

  // --- IAppConfiguration in localStorage (like studio-web's LocalStorageAppConfiguration)
  const CFG_KEY = "op3dsg-check.app-configuration";
  class LocalStorageAppConfiguration {
    constructor(defaults) {
      this.defaults = defaults;
      this.listeners = new Map();
      try { this.values = JSON.parse(localStorage.getItem(CFG_KEY) || "{}"); } catch { this.values = {}; }
    }
    get(key) { return key in this.values ? this.values[key] : this.defaults[key]; }
    async set(key, value) {
      if (value === undefined) delete this.values[key]; else this.values[key] = value;
      localStorage.setItem(CFG_KEY, JSON.stringify(this.values));
      for (const cb of [...(this.listeners.get(key) || [])]) cb(value);
    }
    addChangeListener(key, cb) {
      if (!this.listeners.has(key)) this.listeners.set(key, new Set());
      this.listeners.get(key).add(cb);
    }
    removeChangeListener(key, cb) { this.listeners.get(key)?.delete(cb); }
  }

  // --- ILayoutStorage in localStorage (studio-web uses IndexedDB; same interface)
  const LAYOUT_KEY = "op3dsg-check.layouts"; // { [namespace]: { [id]: Layout } }
  class LocalStorageLayoutStorage {
    read() { try { return JSON.parse(localStorage.getItem(LAYOUT_KEY) || "{}"); } catch { return {}; } }
    write(all) { localStorage.setItem(LAYOUT_KEY, JSON.stringify(all)); }
    async list(ns) { return Object.values(this.read()[ns] || {}).map((l) => S.migrateLayout(l)); }
    async get(ns, id) { const l = (this.read()[ns] || {})[id]; return l ? S.migrateLayout(l) : undefined; }
    async put(ns, layout) { const all = this.read(); (all[ns] ||= {})[layout.id] = layout; this.write(all); return layout; }
    async delete(ns, id) { const all = this.read(); if (all[ns]) delete all[ns][id]; this.write(all); }
    async importLayouts({ fromNamespace, toNamespace }) {
      const all = this.read(); all[toNamespace] = { ...(all[toNamespace] || {}), ...(all[fromNamespace] || {}) };
      delete all[fromNamespace]; this.write(all);
    }
  }

  async function main() {
    S.installDevtoolsFormatters();
    S.overwriteFetch();
    await S.waitForFonts();
    await S.initI18n();
    const appConfiguration = new LocalStorageAppConfiguration({
      [S.AppSetting.SHOW_DEBUG_PANELS]: false,
      [S.AppSetting.TELEMETRY_ENABLED]: false,
      [S.AppSetting.CRASH_REPORTING_ENABLED]: false,
      [S.AppSetting.UPDATES_ENABLED]: false,
    });
    const layoutStorage = new LocalStorageLayoutStorage();
    const extensionLoaders = [];
    const dataSources = [
      new S.FoxgloveWebSocketDataSourceFactory(),
      new S.RosbridgeDataSourceFactory(),
      new S.McapLocalDataSourceFactory(),
    ];
    ReactDOM.render(
      h(S.App, {
        enableLaunchPreferenceScreen: false,
        deepLinks: [window.location.href],
        dataSources,
        appConfiguration,
        layoutStorage,
        extensionLoaders,
        enableGlobalCss: true,
      }),
      document.getElementById("root"),
    );
    console.debug("App rendered");
  }
  main().catch((err) => { console.error("shell failed", err); document.body.setAttribute("data-shell-error", String(err)); });
})();
