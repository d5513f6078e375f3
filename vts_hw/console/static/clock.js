// Times on the console's pages as every file, report and log of vts-hw says them: ISO 8601, in UTC,
// never in the browser's locale or time zone. Loaded before each page's own script. ``t``: seconds
// since the epoch (the server's clock, as the pages receive it).
window.vtsClock = Object.freeze({
  time: (t) => new Date(t * 1000).toISOString().slice(11, 19) + " UTC",                   // 14:03:07 UTC
  stamp: (t) => new Date(t * 1000).toISOString().slice(0, 19).replace("T", " ") + " UTC",  // 2026-11-29 14:03:07 UTC
});
