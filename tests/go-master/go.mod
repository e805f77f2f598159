module handwheel/gomaster

go 1.22

require github.com/samsamfire/gocanopen v1.4.4

require (
	golang.org/x/sys v0.21.0 // indirect
	gopkg.in/ini.v1 v1.67.0 // indirect
)
