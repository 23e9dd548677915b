// The theme before first paint: no white flash on a dark deck. A classic script (not a module), so it
// runs before the page is drawn; a file of its own, since the Content-Security-Policy forbids inline scripts.
document.documentElement.dataset.theme = localStorage.getItem("camcal.theme") || "night";
