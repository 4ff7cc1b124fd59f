// End-to-end tests of the web client in headless Chromium (playwright-core driving Debian's
// chromium) against a real cathlab-server serving the built client (dist/). Prints one
// `test result:` line like cargo's, saves screenshots to test-results/, exits 1 on failure.
//
//   node e2e/run.mjs [--server PATH] [--chromium PATH] [--only REGEX]
//
// The server defaults to ../target/debug/cathlab-server (built by `cargo test`). `--only`
// runs the tests whose names match (the others are skipped, not counted; most tests after
// the first rely on the ones before them, the link-safety ones do not).
//
// This file is the ordered list of checks; they live beside it, by concern: harness.mjs
// (command line, test runner), server.mjs (the server process), page.mjs (page helpers),
// credentials.mjs (links, keys and origins), trainee.mjs, instructor.mjs, instruments.mjs
// (several-instrument scenes) and report.mjs.
import { mkdtempSync, rmSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";
import { chromium } from "playwright-core";
import { anotherServerGetsNothing, linkKeyWaitsForConnect, signInLinkAsksFirst } from "./credentials.mjs";
import { artifacts, assert, chromiumPath, results, test } from "./harness.mjs";
import { assessmentWithoutGuidance, dashboardListsTheSession, observerCannotCommand } from "./instructor.mjs";
import { accessScene, strokeScene, twoHands } from "./instruments.mjs";
import { twoSessionsAndTheReport } from "./report.mjs";
import { pageShowsReconnecting, sessionEndedAfterARestart, startServer } from "./server.mjs";
import {
  buttonsPullBack,
  dsaRoadmapMarksTheTarget,
  framesChangeAfterAPush,
  keysDriveWithAControlFocused,
  layoutsFit,
  loadsAndConnects,
} from "./trainee.mjs";

const dir = mkdtempSync(join(tmpdir(), "cathlab-e2e-"));
const { child: server, url } = await startServer(dir);
const browser = await chromium.launch({
  executablePath: chromiumPath,
  args: [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
  ],
});
// The trainee and the instructor are different people on different machines: separate
// browser contexts (separate connection pools, storage and focus).
const context = await browser.newContext({ viewport: { width: 1280, height: 860 } });
const instructor = await browser.newContext({ viewport: { width: 1280, height: 860 } });
const pageErrors = [];
const trainee = await context.newPage();
trainee.on("pageerror", (e) => pageErrors.push(`trainee: ${e.message}`));
if (process.env.E2E_DEBUG) {
  trainee.on("console", (m) => console.log(`  [trainee console] ${m.text()}`));
  trainee.on("response", (r) => console.log(`  [trainee] ${r.status()} ${r.url()}`));
}
// What the checks share: the server (replaced by a restart), the pages, and what earlier
// checks found (the trainee's session, the distance to go at its start, the observer page).
const ctx = {
  dir, url, server, browser, instructor, trainee, pageErrors,
  sessionId: "", toGoAtStart: Number.NaN, observer: undefined,
};

try {
  await test("links_naming_another_server_send_it_nothing", () => anotherServerGetsNothing(ctx));
  await test("a_link_key_is_not_kept_or_used_until_connect", () => linkKeyWaitsForConnect(ctx));
  await test("trainee_page_loads_and_connects", () => loadsAndConnects(ctx));
  // After the first session: the scene is loaded, so this one's session starts at once.
  await test("a_sign_in_link_changes_the_account_only_when_the_trainee_accepts", () => signInLinkAsksFirst(ctx));
  await test("fluoroscopy_frames_render_and_change_after_a_push", () => framesChangeAfterAPush(ctx));
  await test("on_screen_buttons_pull_back", () => buttonsPullBack(ctx));
  await test("keys_drive_the_device_with_a_slider_or_a_dropdown_focused", () => keysDriveWithAControlFocused(ctx));
  await test("a_dsa_run_shows_the_arch_vessels_on_the_roadmap_with_the_target_marked", () => dsaRoadmapMarksTheTarget(ctx));
  await test("dashboard_lists_the_session_with_thumbnail_metrics_and_timeline", () => dashboardListsTheSession(ctx));
  await test("the_observer_view_cannot_command", () => observerCannotCommand(ctx));
  await test("an_instructor_starts_an_assessment_session_without_guidance", () => assessmentWithoutGuidance(ctx));
  await test("two_hands_drive_their_own_instruments_the_stack_panel_and_the_observer_follow", () => twoHands(ctx));
  await test("stroke_scene_thrombectomy_panel_grade_and_demonstration", () => strokeScene(ctx));
  await test("access_scene_takes_the_innermost_out_and_loads_another", () => accessScene(ctx));
  await test("layouts_fit_1280x800_and_1024x640_without_scrolling", () => layoutsFit(ctx));
  await test("a_trainee_finishes_two_sessions_and_reads_the_report_replay_csv_and_learning_curve", () =>
    twoSessionsAndTheReport(ctx));
  await test("the_page_shows_reconnecting_when_the_server_goes", () => pageShowsReconnecting(ctx));
  await test("after_a_server_restart_the_page_says_the_session_ended", () => sessionEndedAfterARestart(ctx));
  await test("no_script_errors_on_any_page", async () => {
    assert(pageErrors.length === 0, pageErrors.join("\n"));
  });
} finally {
  await browser.close();
  ctx.server.stdin.end();
  ctx.server.kill();
  rmSync(dir, { recursive: true, force: true });
}
const failed = results.filter((r) => !r.ok).length;
console.log(`test result: ${failed ? "FAILED" : "ok"}. ${results.length - failed} passed; ${failed} failed; screenshots in ${artifacts}`);
process.exit(failed ? 1 : 0);
