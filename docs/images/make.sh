#!/usr/bin/env bash
# Makes every picture in docs/images (the README's "Pictures"): runs each scene, then
# renders its frames with its obstacles (`largestep render FRAMES --scene SCENE`) at the
# size given here. The jello world file is read from ../shared/data, beside the
# repository. Run from the repository root; the runs go to out/images/.
set -euo pipefail
cargo build --release --quiet
ls=target/release/largestep
work=out/images
mkdir -p "$work"
# picture name, scene, frame size, what the page shows (the animation or the contact sheet)
while read -r name scene size pick; do
  echo "$name: $scene"
  "$ls" run "$scene" --out "$work/$name" >/dev/null
  "$ls" render "$work/$name/frames" --scene "$scene" --size "$size" \
    --out "$work/$name/preview" >/dev/null
  cp "$work/$name/preview/$pick" "docs/images/$name.${pick##*.}"
done <<'LIST'
jello ../shared/data/jello-worlds/jello.w 640x360 animation.gif
spring-grid scenes/spring-grid.toml 640x360 contact-sheet.png
cloth-drape scenes/cloth-drape.toml 1280x720 contact-sheet.png
flag scenes/flag.toml 1280x720 contact-sheet.png
tablecloth scenes/tablecloth.toml 1280x720 contact-sheet.png
hanging-chain scenes/hanging-chain.toml 640x360 animation.gif
fem-nut scenes/fem-nut.toml 1280x720 contact-sheet.png
fem-ball scenes/fem-ball.toml 640x360 animation.gif
LIST
