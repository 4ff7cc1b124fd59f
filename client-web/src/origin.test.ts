import { describe, expect, it } from "vitest";
import {
  accountOffer,
  chooseServer,
  httpOrigin,
  mayUse,
  needsAllowList,
  parseAllowList,
  savedSessionFor,
  takeSecrets,
} from "./origin.js";

const PAGE = "http://127.0.0.1:50051";

describe("httpOrigin", () => {
  it("reduces an http(s) URL to its origin, the default port dropped", () => {
    expect(httpOrigin("http://127.0.0.1:50051/")).toBe("http://127.0.0.1:50051");
    expect(httpOrigin("HTTPS://Fleet.Example:443/dashboard.html?x=1")).toBe("https://fleet.example");
    expect(httpOrigin("http://a.example:80")).toBe("http://a.example");
  });
  it("refuses other schemes, relative URLs and credentials in the URL", () => {
    for (const bad of ["javascript:alert(1)", "data:text/html,x", "file:///etc/passwd", "//evil.example", "/x", "", "ftp://a"]) {
      expect(httpOrigin(bad), bad).toBeUndefined();
    }
    expect(httpOrigin("http://good.example@evil.example")).toBeUndefined();
  });
});

describe("parseAllowList", () => {
  it("reads the origins of {origins: [...]} normalized, leaving out what is not http(s)", () => {
    expect(
      parseAllowList({ origins: ["http://10.0.0.2:7000/", "https://b.example:443", "javascript:x", 7, "http://10.0.0.2:7000"] }),
    ).toEqual(["http://10.0.0.2:7000", "https://b.example"]);
  });
  it("lists none for an answer of another shape", () => {
    for (const body of [null, undefined, "http://a", ["http://a"], {}, { origins: "http://a" }]) {
      expect(parseAllowList(body)).toEqual([]);
    }
  });
});

describe("chooseServer", () => {
  const listed = ["http://10.0.0.2:7000"];
  it("is this page's origin without ?server= or when it names this origin", () => {
    expect(chooseServer(PAGE, null, [])).toEqual({ kind: "this", origin: PAGE });
    expect(chooseServer(PAGE, "", [])).toEqual({ kind: "this", origin: PAGE });
    expect(chooseServer(PAGE, "http://127.0.0.1:50051/", [])).toEqual({ kind: "this", origin: PAGE });
  });
  it("takes another origin only when the page's server lists it", () => {
    expect(chooseServer(PAGE, "http://10.0.0.2:7000/", listed)).toEqual({ kind: "listed", origin: "http://10.0.0.2:7000" });
    expect(chooseServer(PAGE, "http://127.0.0.1:9999", listed)).toEqual({
      kind: "refused",
      requested: "http://127.0.0.1:9999",
      reason: "not listed",
    });
    // The same host on another port or scheme is another origin.
    expect(chooseServer(PAGE, "https://10.0.0.2:7000", listed).kind).toBe("refused");
    expect(chooseServer(PAGE, "http://10.0.0.2:7001", listed).kind).toBe("refused");
  });
  it("refuses what is not an http(s) origin", () => {
    expect(chooseServer(PAGE, "javascript:alert(1)", listed).kind).toBe("refused");
    expect(chooseServer(PAGE, "evil.example", listed).kind).toBe("refused");
  });
  it("fetches the list only for another http(s) origin", () => {
    expect(needsAllowList(PAGE, null)).toBe(false);
    expect(needsAllowList(PAGE, "http://127.0.0.1:50051")).toBe(false);
    expect(needsAllowList(PAGE, "javascript:x")).toBe(false);
    expect(needsAllowList(PAGE, "http://127.0.0.1:9999")).toBe(true);
  });
});

describe("mayUse", () => {
  it("lets credentials go to this origin and listed ones only", () => {
    expect(mayUse(PAGE, "http://127.0.0.1:50051/x", [])).toBe(true);
    expect(mayUse(PAGE, "http://10.0.0.2:7000", ["http://10.0.0.2:7000"])).toBe(true);
    expect(mayUse(PAGE, "http://10.0.0.3:7000", ["http://10.0.0.2:7000"])).toBe(false);
    expect(mayUse(PAGE, "not a url", [])).toBe(false);
  });
});

describe("takeSecrets", () => {
  it("takes account, token and key out of the address, keeping the rest", () => {
    const { clean, secrets, changed } = takeSecrets(
      "http://h:1/index.html?session=S&token=T&role=observer&account=A&key=K&account=B#x",
    );
    expect(changed).toBe(true);
    expect(secrets).toEqual({ token: "T", account: "A", key: "K" });
    const url = new URL(clean);
    expect([...url.searchParams.keys()]).toEqual(["session", "role"]);
    expect(url.hash).toBe("#x");
    expect(clean).not.toMatch(/account|token|key|=A|=B|=K|=T/);
  });
  it("leaves an address without secrets alone; an empty value is no secret but still goes", () => {
    expect(takeSecrets("http://h:1/?session=S").changed).toBe(false);
    const empty = takeSecrets("http://h:1/?account=");
    expect(empty).toEqual({ clean: "http://h:1/", secrets: {}, changed: true });
  });
});

describe("accountOffer", () => {
  it("asks before a link's account is kept, saying whether it replaces one", () => {
    expect(accountOffer(undefined, "mine")).toEqual({ kind: "none" });
    expect(accountOffer("mine", "mine")).toEqual({ kind: "same" });
    expect(accountOffer("theirs", "mine")).toEqual({ kind: "ask", token: "theirs", replaces: true });
    expect(accountOffer("theirs", null)).toEqual({ kind: "ask", token: "theirs", replaces: false });
    expect(accountOffer("theirs", "")).toEqual({ kind: "ask", token: "theirs", replaces: false });
  });
});

describe("savedSessionFor", () => {
  const saved = JSON.stringify({ origin: PAGE, id: "S1", token: "T1", readOnly: true });
  it("gives a tab's saved session back for the server that issued its token", () => {
    expect(savedSessionFor(saved, PAGE)).toEqual({ origin: PAGE, id: "S1", token: "T1", readOnly: true });
    expect(savedSessionFor(saved, PAGE, "S1")?.token).toBe("T1");
  });
  it("never for another origin, another session or a malformed entry", () => {
    expect(savedSessionFor(saved, "http://127.0.0.1:9999")).toBeUndefined();
    expect(savedSessionFor(saved, PAGE, "S2")).toBeUndefined();
    // The old shape (no origin) is not trusted.
    expect(savedSessionFor(JSON.stringify({ id: "S1", token: "T1" }), PAGE)).toBeUndefined();
    expect(savedSessionFor("{", PAGE)).toBeUndefined();
    expect(savedSessionFor(null, PAGE)).toBeUndefined();
  });
});
