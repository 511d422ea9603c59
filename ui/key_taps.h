#pragma once
// Key presses as GLFW reports them between two frames. Dear ImGui 1.86 polls the keys' state once
// a frame, so a tap shorter than a frame (a quick Space while a slow view renders) never shows as
// pressed; the transport keys read these events as well, so that no tap is lost.
struct GLFWwindow;

namespace refocus {

// Records the window's key presses, chaining to the key callback installed before (ImGui's).
void install_key_taps(GLFWwindow* window);
// Was `key` (a GLFW key code) pressed since the last clear_key_taps()?
bool key_tapped(int key);
// Forgets the frame's taps (at the end of each frame).
void clear_key_taps();

}  // namespace refocus
