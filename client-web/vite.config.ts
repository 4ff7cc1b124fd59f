// Three pages: the trainee view (index.html), the instructor dashboard (dashboard.html) and
// the session report (report.html),
// built to dist/ for cathlab-server to serve. `npm run dev` serves them from vite and proxies
// the API (and the fleet's allow-list) to a running server, CATHLAB_SERVER_URL
// (http://127.0.0.1:50051 by default): the pages talk to their own origin, as when the server
// serves them (a `?server=` naming another origin is refused unless that server lists it).
import { resolve } from "node:path";
import { defineConfig } from "vite";

const api = process.env.CATHLAB_SERVER_URL ?? "http://127.0.0.1:50051";

export default defineConfig({
  server: {
    proxy: {
      "/cathlab.v1.Simulator": { target: api, changeOrigin: true },
      "/fleet-origins": { target: api, changeOrigin: true },
    },
  },
  build: {
    outDir: "dist",
    emptyOutDir: true,
    rollupOptions: {
      input: {
        trainee: resolve(import.meta.dirname, "index.html"),
        dashboard: resolve(import.meta.dirname, "dashboard.html"),
        report: resolve(import.meta.dirname, "report.html"),
      },
    },
  },
  test: { include: ["src/**/*.test.ts"], environment: "node" },
});
