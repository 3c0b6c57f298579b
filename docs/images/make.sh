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
cloth-fold scenes/cloth-fold.toml 1280x720 contact-sheet.png
cloth-pinned-bottom scenes/cloth-pinned-bottom.toml 1280x720 contact-sheet.png
hanging-chain scenes/hanging-chain.toml 640x360 animation.gif
fem-nut scenes/fem-nut.toml 1280x720 contact-sheet.png
fem-ball scenes/fem-ball.toml 640x360 animation.gif
rigid-pile scenes/rigid-pile.toml 1280x720 contact-sheet.png
rigid-dominoes scenes/rigid-dominoes.toml 1280x720 contact-sheet.png
rigid-cradle scenes/rigid-cradle.toml 640x360 animation.gif
rigid-t-handle scenes/rigid-t-handle.toml 640x360 animation.gif
rigid-chain scenes/rigid-chain.toml 640x360 animation.gif
rigid-cloth scenes/rigid-cloth.toml 1280x720 contact-sheet.png
rigid-jello scenes/rigid-jello.toml 1280x720 contact-sheet.png
anim-clip scenes/anim-clip.toml 640x360 animation.gif
anim-twist scenes/anim-twist.toml 1280x720 contact-sheet.png
anim-reach scenes/anim-reach.toml 1280x720 contact-sheet.png
anim-walk scenes/anim-walk.toml 640x360 animation.gif
LIST
# The twisted bar: fem-twist (corotational, behind) and fem-twist-linear (linear, in
# front, z + 0.25 m) run apart and drawn in one picture: each frame of the two runs
# merged into one OBJ (the second's face indices shifted past the first's vertices).
for s in fem-twist fem-twist-linear; do
  echo "fem-twist: scenes/$s.toml"
  "$ls" run "scenes/$s.toml" --out "$work/$s" >/dev/null
done
both="$work/fem-twist-both"
rm -rf "$both" && mkdir -p "$both/frames"
for f in "$work/fem-twist/frames"/*.obj; do
  awk 'FNR == 1 { file++ } file == 1 && /^v / { n++ }
       file == 2 && /^f / { print "f", $2 + n, $3 + n, $4 + n; next } { print }' \
    "$f" "$work/fem-twist-linear/frames/$(basename "$f")" > "$both/frames/$(basename "$f")"
done
"$ls" render "$both/frames" --size 1280x720 --out "$both/preview" >/dev/null
cp "$both/preview/contact-sheet.png" docs/images/fem-twist.png
# The sound scenes' spectrograms (`largestep run` draws spectrogram.png beside
# sound.wav).
for s in sound-bar sound-bowl sound-nut sound-rigid-bar; do
  echo "$s: scenes/$s.toml"
  "$ls" run "scenes/$s.toml" --out "$work/$s" >/dev/null
  cp "$work/$s/spectrogram.png" "docs/images/$s-spectrogram.png"
done
# The fluid scenes: their previews are drawn during the run (a colour map of the smoke in
# 2-D, a volume rendering in 3-D) at the scene's preview size.
for s in fluid-smoke-2d fluid-smoke-3d; do
  echo "$s: scenes/$s.toml"
  "$ls" run "scenes/$s.toml" --out "$work/$s" --preview >/dev/null
  cp "$work/$s/preview/contact-sheet.png" "docs/images/$s.png"
done
