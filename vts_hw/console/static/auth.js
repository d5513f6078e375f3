// Who is logged in, and the way out: the user's name and role and a "Log out" button in the page's
// header. When the session ends (its time is up, logged out elsewhere, the user disabled) the page goes
// to the login page, which says so. Without users (the console on this machine only) it shows nothing.
"use strict";
(function () {
  const link = document.createElement("link");
  link.rel = "stylesheet"; link.href = "/static/auth.css";
  document.head.appendChild(link);

  function toLogin() {
    const here = location.pathname + location.search;
    location.assign(`/login?ended=1&next=${encodeURIComponent(here)}`);
  }

  function show(s) {
    if (!s.required || document.getElementById("who")) return;
    const who = document.createElement("div");
    who.id = "who"; who.className = "who";
    who.dataset.user = s.user; who.dataset.role = s.role;
    const name = document.createElement("span");
    name.textContent = `${s.user} `;
    const role = document.createElement("span");
    role.className = "role"; role.textContent = `(${s.role})`;
    const out = document.createElement("button");
    out.type = "button"; out.id = "logout"; out.textContent = "Log out";
    out.addEventListener("click", () => {
      // (the session's page token, as every action of the page carries it)
      fetch("/logout", { method: "POST", credentials: "same-origin", headers: { "X-Console-Token": s.token } })
        .finally(() => location.assign("/login"));
    });
    who.append(name, role, out);
    const header = document.querySelector("header");
    if (header) header.appendChild(who);
  }

  function check() {
    fetch("/session", { cache: "no-store", credentials: "same-origin" })
      .then((r) => {
        if (r.status === 401) { toLogin(); return null; }
        return r.ok ? r.json() : null;
      })
      .then((s) => { if (s) show(s); })
      .catch(() => {});             // the console away: the page's own contact state says so
  }

  document.addEventListener("DOMContentLoaded", check);
  setInterval(check, 3000);
})();
