// Exports: a file made in the page (a plot's PNG or CSV, the command history's CSV) handed to the browser
// as a download through a Blob URL. The link stays in the page (#download: its href and download name) until
// the next export, so a script — or a test — can read the file back.

export function download(blob, name) {
  const a = document.getElementById("download");
  if (a.href && a.href.startsWith("blob:")) URL.revokeObjectURL(a.href);
  a.href = URL.createObjectURL(blob);
  a.download = name;
  a.dataset.name = name;
  a.click();
}

function csvCell(v) {
  if (v === null || v === undefined || (typeof v === "number" && !Number.isFinite(v))) return "";
  const s = String(v);
  return /[",\n\r]/.test(s) ? `"${s.replace(/"/g, '""')}"` : s;
}

// CSV text (RFC 4180: quoted where needed, CRLF line ends) of a header and rows.
export function toCsv(header, rows) {
  return [header, ...rows].map((r) => r.map(csvCell).join(",")).join("\r\n") + "\r\n";
}

export function downloadCsv(name, header, rows) {
  download(new Blob([toCsv(header, rows)], { type: "text/csv" }), name);
}

// A filename part from a run's name (letters, digits, - _ . only).
export function safeName(s) {
  return String(s || "run").replace(/[^A-Za-z0-9_.-]+/g, "_").slice(0, 80);
}
