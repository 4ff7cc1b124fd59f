// Three pages: the trainee view (index.html), the instructor dashboard (dashboard.html) and
// the session report (report.html),
// built to dist/ for cathlab-server to serve. `npm run dev` proxies nothing: point the
// pages at a running server with ?server=http://127.0.0.1:50051.
import { resolve } from "node:path";
import { defineConfig } from "vite";

export default defineConfig({
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
