// The passenger page (a kiosk in the shuttle): the tour's stops, the next one and the time to it,
// the doors and the ramp, the media started at START_MEDIA, and why the shuttle stands, in large
// type and the passenger's language. It reads only /live/passenger: nothing else of the vehicle.
"use strict";

ARES.page(["passenger", "operator"], "passenger", async () => {
  const WORDS = {
    en: {language: "Language", next_stop: "Next stop", at_stop: "This stop", doors: "Doors", ramp: "Ramp",
         media: "Now playing: welcome to the campus", minutes: (m) => m < 1 ? "arriving" : "in " + m + " min",
         closed: "closed", opening: "opening", open: "open", closing: "closing",
         stowed: "stowed", deploying: "coming out", deployed: "out", stowing: "going in",
         emergency: "Emergency stop. Please stay seated: the staff have been told.",
         obstacle: "Something is on the road ahead: we wait until it is clear.",
         intersection: "Stopping at the crossing before we go on.",
         paused: "The shuttle is paused by the operator.",
         at_stop_message: "We are at the stop.", waiting: "Waiting for the road: we go on shortly.", none: ""},
    es: {language: "Idioma", next_stop: "Próxima parada", at_stop: "Esta parada", doors: "Puertas", ramp: "Rampa",
         media: "Reproduciendo: bienvenidos al campus", minutes: (m) => m < 1 ? "llegando" : "en " + m + " min",
         closed: "cerradas", opening: "abriéndose", open: "abiertas", closing: "cerrándose",
         stowed: "recogida", deploying: "saliendo", deployed: "desplegada", stowing: "recogiéndose",
         emergency: "Parada de emergencia. Permanezcan sentados: el personal está avisado.",
         obstacle: "Hay algo en la calzada: esperamos a que quede libre.",
         intersection: "Parada en el cruce antes de seguir.",
         paused: "El operador ha detenido el vehículo.",
         at_stop_message: "Estamos en la parada.", waiting: "Esperando: seguimos enseguida.", none: ""},
    fr: {language: "Langue", next_stop: "Prochain arrêt", at_stop: "Cet arrêt", doors: "Portes", ramp: "Rampe",
         media: "En cours : bienvenue sur le campus", minutes: (m) => m < 1 ? "à l'approche" : "dans " + m + " min",
         closed: "fermées", opening: "s'ouvrent", open: "ouvertes", closing: "se ferment",
         stowed: "rangée", deploying: "sort", deployed: "sortie", stowing: "rentre",
         emergency: "Arrêt d'urgence. Restez assis : le personnel est prévenu.",
         obstacle: "Un obstacle sur la route : nous attendons qu'elle soit libre.",
         intersection: "Arrêt au croisement avant de repartir.",
         paused: "La navette est mise en pause par l'opérateur.",
         at_stop_message: "Nous sommes à l'arrêt.", waiting: "En attente : nous repartons bientôt.", none: ""},
  };
  const select = document.getElementById("language");
  select.value = localStorage.getItem("ares.language") || "en";
  let last = null;
  const $ = (id) => document.getElementById(id);

  function word(key) { const w = WORDS[select.value] || WORDS.en; return key in w ? w[key] : key; }

  function show(f) {
    for (const el of document.querySelectorAll("[data-text]")) el.textContent = word(el.dataset.text);
    if (!f) return;
    $("tour").textContent = f.tour || "";
    $("next-label").textContent = word(f.at_stop ? "at_stop" : "next_stop");
    $("next-stop").textContent = f.next_stop || "–";
    $("next-stop").dataset.value = f.next_stop || "";
    $("eta").textContent = f.eta_s == null || f.at_stop ? "" : word("minutes")(Math.round(f.eta_s / 60));
    const reason = f.reason || "none";
    $("message").dataset.reason = reason;
    $("message").textContent = word(reason === "at_stop" ? "at_stop_message" : reason);
    for (const part of ["doors", "ramp"]) {
      $(part).dataset.value = f[part] || "";
      $(part).textContent = f[part] ? word(f[part]) : "";
    }
    $("media").hidden = !f.media;
    $("media").dataset.playing = f.media ? "true" : "false";
    const stops = $("stops");
    stops.replaceChildren();
    for (const name of f.stops || []) {
      const li = ARES.text("li", name, name === f.next_stop ? "next" : "");
      stops.append(li);
    }
  }

  select.addEventListener("change", () => { localStorage.setItem("ares.language", select.value); show(last); });
  show(null);
  ARES.stream("/live/passenger", {
    frame(f) { last = f; show(f); },
    error(why) { $("message").textContent = why; },
  });
});
